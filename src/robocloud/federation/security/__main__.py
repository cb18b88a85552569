"""``python -m robocloud.federation.security make-certs ...``."""

import sys

from robocloud.federation.security.certificates import main

sys.exit(main())
