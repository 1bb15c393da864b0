// Keeps a queue lease alive while its task is on screen (or prefetched), and lets it go on request.
export class LeaseKeeper {
  constructor(api, queue) {
    this.api = api;
    this.queue = queue; // "annotate" | "review"
    this.leases = new Map(); // sample id -> {token, expiresAt (ms), timer}
  }

  hold(task) {
    this.drop(task.sample_id, false);
    const expiresAt = Date.parse(task.lease_expires_at);
    const lifetime = Math.max(5000, expiresAt - Date.now());
    const lease = { token: task.lease_token, expiresAt, timer: null };
    const renew = async () => {
      try {
        const body = await this.api.post(`/api/${this.queue}/samples/${task.sample_id}/lease/renew`,
          { lease_token: lease.token });
        lease.expiresAt = Date.parse(body.lease_expires_at);
      } catch (error) {
        lease.error = error;
      }
    };
    lease.timer = setInterval(renew, Math.min(60000, lifetime / 3));
    this.leases.set(task.sample_id, lease);
  }

  expiresAt(sampleId) {
    const lease = this.leases.get(sampleId);
    return lease ? lease.expiresAt : null;
  }

  // Stop renewing; with release=true also hand the sample back to the queue now.
  drop(sampleId, release = true) {
    const lease = this.leases.get(sampleId);
    if (!lease) return Promise.resolve();
    clearInterval(lease.timer);
    this.leases.delete(sampleId);
    if (!release) return Promise.resolve();
    return this.api.post(`/api/${this.queue}/samples/${sampleId}/lease/release`, { lease_token: lease.token })
      .catch(() => null);
  }

  dropAll(release = true) {
    return Promise.all([...this.leases.keys()].map((id) => this.drop(id, release)));
  }
}
