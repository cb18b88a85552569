// Truthful sending. One form submission is one Idempotency-Key, reused on
// every retry: an IaaS that already holds the request answers with it, so a
// retry never sends robots twice. The page says only what it knows:
//
//   sending        the first try is on its way
//   unconfirmed    a try may have reached the IaaS and no answer came: the
//                  request may exist; the page keeps sending the same key
//                  until an answer says which (never "not sent")
//   not sent yet   every try so far was refused before reaching any IaaS
//                  (none answers): it keeps trying
//   confirmed      the IaaS answered with the request
//   refused        the IaaS (or the wildfire server) said no, with its sentence
//   stopped        the operator stopped checking; if a try may have arrived,
//                  the page says so and the request will show in the list

const BACKOFF_S = [2, 3, 5, 8, 10];

// While a send is not settled: the button's word and the line under it, for
// "the request" or "the mission". Null once it is settled.
export function pendingLine(submission, what, detail) {
  switch (submission.state) {
    case "sending":
      return { button: "Sending…", text: "Sending…" };
    case "unconfirmed":
      return { button: "Checking…", text: `Not confirmed yet: ${detail} The ${what} may have reached the IaaS; checking again with the same key `
        + `in ${submission.retryIn} s (try ${submission.attempts + 1}), so it cannot be sent twice.` };
    case "not-sent-yet":
      return { button: "Trying…", text: `No IaaS has received it yet: ${detail} Trying again in ${submission.retryIn} s (try ${submission.attempts + 1}).` };
    default:
      return null;
  }
}

export function newKey() {
  const bytes = new Uint8Array(16);
  crypto.getRandomValues(bytes);
  return `wf-${[...bytes].map((b) => b.toString(16).padStart(2, "0")).join("")}`;
}

export class Sender {
  constructor({ api, onChange }) {
    this.api = api;
    this.onChange = onChange;
    this.current = null;
  }

  busy() {
    return Boolean(this.current && ["sending", "unconfirmed", "not-sent-yet"].includes(this.current.state));
  }

  async submit(task) {
    if (this.busy()) return this.current;
    const submission = { key: newKey(), task, attempts: 0, maybeDelivered: false, state: "sending",
      detail: null, request: null, retryIn: 0, timer: null, since: Date.now() };
    this.current = submission;
    this.onChange(submission);
    await this.attempt(submission);
    return submission;
  }

  async attempt(submission) {
    if (this.current !== submission || submission.state === "stopped") return;
    submission.attempts += 1;
    const answer = await this.api.send(submission.task, submission.key);
    if (this.current !== submission || submission.state === "stopped") return;
    if (answer.ok) {
      submission.state = "confirmed";
      submission.request = answer.data;
      submission.detail = null;
      this.onChange(submission);
      return;
    }
    if (answer.delivery === "refused" || (answer.status >= 400 && answer.status < 500 && answer.status !== 408 && answer.status !== 429)) {
      // An answer that refuses is final: nothing was made for this key.
      submission.state = "refused";
      submission.status = answer.status;
      submission.detail = answer.detail;
      this.onChange(submission);
      return;
    }
    if (answer.delivery !== "none") submission.maybeDelivered = true;
    submission.state = submission.maybeDelivered ? "unconfirmed" : "not-sent-yet";
    submission.detail = answer.detail;
    const wait = BACKOFF_S[Math.min(submission.attempts - 1, BACKOFF_S.length - 1)];
    submission.retryIn = wait;
    this.onChange(submission);
    submission.timer = setTimeout(() => this.attempt(submission), wait * 1000);
  }

  // A new submission begins: the line under the form stops following the last one.
  forget() {
    if (!this.busy()) this.current = null;
  }

  stop() {
    const submission = this.current;
    if (!submission || !this.busy()) return;
    clearTimeout(submission.timer);
    submission.state = "stopped";
    this.onChange(submission);
  }
}
