// Keeps a queue lease alive while its task is on screen (or prefetched), and lets it go on request. A lease
// that lapsed (the server was unreachable, the laptop slept) is re-taken at once while nobody else holds
// the sample (POST .../lease/retake); when someone does, `onlost(sampleId, error)` tells the page.
import { paths } from "./api.js";

export class LeaseKeeper {
  constructor(api, queue) {
    this.api = api;
    this.queue = queue; // "annotate" | "review"
    this.leases = new Map(); // sample id -> {token, expiresAt (ms), timer}
    /** @type {(sampleId: number, token: string) => void} */
    this.onretaken = () => {};
    /** @type {(sampleId: number, error: any) => void} */
    this.onlost = () => {};
  }

  hold(task) {
    this.drop(task.sample_id, false);
    const expiresAt = Date.parse(task.lease_expires_at);
    const lifetime = Math.max(5000, expiresAt - Date.now());
    const lease = { token: task.lease_token, expiresAt, timer: null };
    const renew = async () => {
      if (lease.lost) return;
      try {
        const body = await this.api.post(paths.leaseRenew(this.queue, task.sample_id),
          { lease_token: lease.token });
        lease.expiresAt = Date.parse(body.lease_expires_at);
        lease.error = null;
      } catch (error) {
        lease.error = error; // unreachable: tried again at the next tick
        if (error.status === 403 || error.status === 409) await this.retake(task.sample_id).catch(() => null);
      }
    };
    lease.timer = setInterval(renew, Math.min(60000, lifetime / 3));
    this.leases.set(task.sample_id, lease);
  }

  expiresAt(sampleId) {
    const lease = this.leases.get(sampleId);
    return lease ? lease.expiresAt : null;
  }

  token(sampleId) {
    const lease = this.leases.get(sampleId);
    return lease ? lease.token : null;
  }

  // Take the lease again after it lapsed; resolves to the (possibly new) token, or rejects with the
  // server's reason (someone else holds the sample, it left the queue) after telling onlost.
  async retake(sampleId) {
    const lease = this.leases.get(sampleId);
    if (!lease) throw new Error(`no lease kept for sample ${sampleId}`);
    if (lease.retaking) return lease.retaking;
    lease.retaking = this.api.post(paths.leaseRetake(this.queue, sampleId), { lease_token: lease.token })
      .then((body) => {
        lease.token = body.lease_token;
        lease.expiresAt = Date.parse(body.lease_expires_at);
        lease.error = null;
        this.onretaken(sampleId, lease.token);
        return lease.token;
      }, (error) => {
        if (error.status === 403 || error.status === 409) {
          lease.lost = error;
          clearInterval(lease.timer);
          this.onlost(sampleId, error);
        }
        throw error;
      })
      .finally(() => { lease.retaking = null; });
    return lease.retaking;
  }

  // Stop renewing; with release=true also hand the sample back to the queue now.
  drop(sampleId, release = true) {
    const lease = this.leases.get(sampleId);
    if (!lease) return Promise.resolve();
    clearInterval(lease.timer);
    this.leases.delete(sampleId);
    if (!release || lease.lost) return Promise.resolve();
    return this.api.post(paths.leaseRelease(this.queue, sampleId), { lease_token: lease.token })
      .catch(() => null);
  }

  dropAll(release = true) {
    return Promise.all([...this.leases.keys()].map((id) => this.drop(id, release)));
  }
}
