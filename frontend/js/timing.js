// Time per action. Each action's duration is the working time since the previous one; the sum of durations is
// the task's time spent. Two rules for a pause (coffee, another tab):
// - capped (the default, the review page): the time since the previous action counts up to idleCapMs;
// - dropIdle (the annotate page, docs/ui.md "every count counts what it says"): time counts between inputs
//   (input(): pointer moves, keys, wheel; every action is one), a gap with no input longer than idleCapMs
//   counts nothing at all, and nothing counts while paused (the tab hidden) until the next input.
export class ActionTimer {
  constructor({ idleCapMs = 30000, dropIdle = false, now = () => performance.now() } = {}) {
    this.idleCapMs = idleCapMs;
    this.dropIdle = dropIdle;
    this.now = now;
    this.carriedMs = 0; // time spent before a reload, from the restored draft
    this.start();
  }

  start() {
    this.t0 = this.now();
    this.last = this.t0; // the previous action
    this.lastInput = this.t0; // the previous input (dropIdle)
    this.activeMs = 0; // working time counted up to lastInput (dropIdle)
    this.markedMs = 0; // activeMs at the previous action (dropIdle)
    this.paused = false;
    this.actions = [];
  }

  // What a gap since the previous input adds: all of it up to idleCapMs, nothing beyond (dropIdle).
  gapMs(t = this.now()) {
    const gap = t - this.lastInput;
    return this.paused || gap > this.idleCapMs ? 0 : gap;
  }

  // An input event: the gap before it counts by the dropIdle rule.
  input(t = this.now()) {
    this.activeMs += this.gapMs(t);
    this.lastInput = t;
    this.paused = false;
  }

  // The tab was hidden: the time up to now counts, none after it until the next input.
  pause() {
    this.input();
    this.paused = true;
  }

  // Whether the clock stands still now (dropIdle: paused, or no input for longer than idleCapMs).
  idle() {
    return this.dropIdle && (this.paused || this.now() - this.lastInput > this.idleCapMs);
  }

  mark(kind, extra = {}) {
    const t = this.now();
    let duration;
    if (this.dropIdle) {
      this.input(t);
      duration = this.activeMs - this.markedMs;
      this.markedMs = this.activeMs;
    } else {
      duration = Math.min(t - this.last, this.idleCapMs);
    }
    const action = {
      kind,
      at_ms: Math.round((t - this.t0) * 10) / 10,
      duration_ms: Math.round(duration * 10) / 10,
      ...extra,
    };
    this.last = t;
    this.actions.push(action);
    return action;
  }

  // Active seconds so far (plus the time carried over from a restored draft): the logged durations plus the
  // time since the last action, by the rule above.
  spentSeconds() {
    if (this.dropIdle) return (this.carriedMs + this.activeMs + this.gapMs()) / 1000;
    const logged = this.actions.reduce((sum, a) => sum + a.duration_ms, 0);
    return (this.carriedMs + logged + Math.min(this.now() - this.last, this.idleCapMs)) / 1000;
  }
}
