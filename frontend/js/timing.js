// Time per action. Each action's duration is the time since the previous one, capped so that a pause
// (coffee, another tab) does not count as work; the sum of durations is the task's time spent.
export class ActionTimer {
  constructor({ idleCapMs = 30000, now = () => performance.now() } = {}) {
    this.idleCapMs = idleCapMs;
    this.now = now;
    this.carriedMs = 0; // time spent before a reload, from the restored draft
    this.start();
  }

  start() {
    this.t0 = this.now();
    this.last = this.t0;
    this.actions = [];
  }

  mark(kind, extra = {}) {
    const t = this.now();
    const action = {
      kind,
      at_ms: Math.round((t - this.t0) * 10) / 10,
      duration_ms: Math.round(Math.min(t - this.last, this.idleCapMs) * 10) / 10,
      ...extra,
    };
    this.last = t;
    this.actions.push(action);
    return action;
  }

  // Active seconds so far: the capped durations plus the (capped) time since the last action (plus the
  // time carried over from a restored draft).
  spentSeconds() {
    const logged = this.actions.reduce((sum, a) => sum + a.duration_ms, 0);
    return (this.carriedMs + logged + Math.min(this.now() - this.last, this.idleCapMs)) / 1000;
  }
}
