"""The one place where a command's end becomes an exit code and one sentence on stderr.

``run(command, args, name)`` runs a parsed command (``robocloud``'s
subcommands, and ``python -m robocloud.sim.command`` / ``robocloud.wildfire.command``
which are the same commands under another entry point):

- 0: done (also a server stopped by SIGINT or SIGTERM);
- 2: the user's input is wrong (``InvalidInput``, ``NotFound``), and argparse's
  own usage errors (argparse exits with 2 itself);
- 1: anything else that stops a command: a store that cannot be reached, a
  port in use (other ``RoboCloudError``), or an error nobody foresaw;
- 130: interrupted while starting.

The user reads one sentence, never a traceback; ``--log-level debug`` prints
the traceback before it.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from collections.abc import Callable

from robocloud import logs
from robocloud.errors import InvalidInput, NotFound, RoboCloudError

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_INVALID = 2
EXIT_INTERRUPTED = 130

Command = Callable[[argparse.Namespace], int]


def exit_code(error: RoboCloudError) -> int:
    """What a user error exits with."""
    if isinstance(error, InvalidInput | NotFound):
        return EXIT_INVALID
    return EXIT_FAILED


def run(command: Command, args: argparse.Namespace, name: str = "the command") -> int:
    """``command(args)``, every way it can end turned into an exit code and a sentence."""
    logs.install()  # every log line of every command escapes control characters
    # getattr: a command may have no --log-level.
    debug = getattr(args, "log_level", "") == "debug"
    try:
        return command(args)
    except RoboCloudError as error:
        if debug:
            traceback.print_exc()
        say(error.message)
        return exit_code(error)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader went away (``| head``); keep Python from complaining at exit.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_FAILED
    except Exception as error:  # a failure nobody foresaw: still one sentence
        if debug:
            traceback.print_exc()
        first = (str(error).strip().splitlines() or [""])[0].rstrip(".")
        say(
            f"{name} stopped on an unexpected {type(error).__name__}"
            f"{': ' + first if first else ''}; run it again with --log-level debug "
            "to see where."
        )
        return EXIT_FAILED


def say(message: str) -> None:
    """The one line on stderr an error becomes, whatever the message holds."""
    print(f"robocloud: {' '.join(message.split())}", file=sys.stderr)
