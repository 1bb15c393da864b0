"""A small typed client of handloop's HTTP API (docs/api.md), one per signed-in user.

It takes any `httpx.Client` bound to the server: `httpx.Client(base_url=...)` for a running server, or
FastAPI's TestClient (an httpx.Client) in tests. Errors come back as `ApiError` with the server's detail.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import httpx

log = logging.getLogger(__name__)


class ApiError(RuntimeError):
    """A request the server refused; `status` and `detail` are the server's."""

    def __init__(self, method: str, path: str, status: int, detail: Any) -> None:
        super().__init__(f"{method} {path} -> {status}: {detail}")
        self.method, self.path, self.status, self.detail = method, path, status, detail


def login(http: httpx.Client, email: str, password: str) -> str:
    """A bearer token for the user (OAuth2 password form)."""
    response = http.post("/api/auth/token", data={"username": email, "password": password})
    if response.status_code != 200:
        raise ApiError("POST", "/api/auth/token", response.status_code, _detail(response))
    return response.json()["access_token"]


def _detail(response: httpx.Response) -> Any:
    try:
        return response.json().get("detail", response.text)
    except ValueError:
        return response.text


class ApiClient:
    """One user's view of the API. Busy answers (503: database or broker busy) are retried briefly."""

    def __init__(self, http: httpx.Client, token: str, *, retries_on_busy: int = 5) -> None:
        self.http = http
        self.headers = {"Authorization": f"Bearer {token}"}
        self.retries_on_busy = retries_on_busy

    @classmethod
    def sign_in(cls, http: httpx.Client, email: str, password: str) -> ApiClient:
        return cls(http, login(http, email, password))

    def request(self, method: str, path: str, *, expect: tuple[int, ...] = (200,), **kwargs: Any) -> httpx.Response:
        for attempt in range(self.retries_on_busy + 1):
            response = self.http.request(method, path, headers=self.headers, **kwargs)
            if response.status_code != 503 or attempt == self.retries_on_busy:
                break
            time.sleep(0.2 * (attempt + 1))
        if response.status_code not in expect:
            raise ApiError(method, path, response.status_code, _detail(response))
        return response

    def get_json(self, path: str, **params: Any) -> Any:
        return self.request("GET", path, params={k: v for k, v in params.items() if v is not None}).json()

    # --- annotator -------------------------------------------------------------------------------------
    def next_annotation(self) -> dict[str, Any] | None:
        response = self.request("POST", "/api/annotate/next", expect=(200, 204))
        return None if response.status_code == 204 else response.json()

    def submit(self, sample_id: int, body: dict[str, Any]) -> dict[str, Any]:
        return self.request("POST", f"/api/annotate/samples/{sample_id}/submissions", expect=(200, 201),
                            json=body).json()

    def proposals(self, sample_id: int) -> dict[str, Any]:
        return self.get_json(f"/api/annotate/samples/{sample_id}/proposals")

    def release_annotation(self, sample_id: int, lease_token: str) -> None:
        self.request("POST", f"/api/annotate/samples/{sample_id}/lease/release", expect=(204,),
                     json={"lease_token": lease_token})

    def file(self, url: str) -> bytes:
        return self.request("GET", url).content

    # --- reviewer --------------------------------------------------------------------------------------
    def next_review(self) -> dict[str, Any] | None:
        response = self.request("POST", "/api/review/next", expect=(200, 204))
        return None if response.status_code == 204 else response.json()

    def decide(self, sample_id: int, decision: str, lease_token: str, reason: str = "") -> dict[str, Any]:
        return self.request("POST", f"/api/review/samples/{sample_id}/decision", expect=(201,),
                            json={"decision": decision, "reason": reason, "lease_token": lease_token}).json()

    # --- admin -----------------------------------------------------------------------------------------
    def create_user(self, email: str, password: str, role: str, full_name: str = "") -> dict[str, Any]:
        return self.request("POST", "/api/admin/users", expect=(201,),
                            json={"email": email, "password": password, "role": role, "full_name": full_name}).json()

    def import_capture(self, path: str, project: str, queue_for_annotation: bool) -> dict[str, Any]:
        return self.request("POST", "/api/admin/imports", expect=(201,),
                            json={"path": path, "project": project,
                                  "queue_for_annotation": queue_for_annotation}).json()

    def preannotation(self) -> dict[str, Any]:
        """Whether the detector can run on the server, and its projects."""
        return self.get_json("/api/admin/preannotation")

    def preannotate(self, project_id: int, sample_ids: list[int] | None = None, rest: str = "keep"
                    ) -> dict[str, Any]:
        body: dict[str, Any] = {"project_id": project_id, "rest": rest}
        if sample_ids is not None:
            body["sample_ids"] = sample_ids
        return self.request("POST", "/api/admin/preannotation", expect=(202,), json=body).json()

    def launch_round(self, note: str = "") -> dict[str, Any]:
        return self.request("POST", "/api/admin/rounds", expect=(201,), json={"note": note}).json()

    def rounds(self) -> list[dict[str, Any]]:
        return self.get_json("/api/admin/rounds")

    def statistics(self) -> dict[str, Any]:
        return self.get_json("/api/admin/rounds/statistics")

    def build_review_queue(self) -> list[int]:
        return self.request("POST", "/api/admin/rounds/review-queue").json()["queued"]

    def job(self, job_id: int) -> dict[str, Any]:
        return self.get_json(f"/api/admin/jobs/{job_id}")

    def jobs(self, state: str | None = None, kind: str | None = None, limit: int = 1000) -> list[dict[str, Any]]:
        return self.get_json("/api/admin/jobs", state=state, kind=kind, limit=limit)

    def dataset(self, up_to_round: int | None = None) -> dict[str, Any]:
        return self.get_json("/api/admin/exports/dataset", up_to_round=up_to_round)

    def sample_index(self, project: str | None = None) -> dict[str, Any]:
        return self.get_json("/api/admin/exports/samples", project=project)

    def queue_for_annotation(self, sample_ids: list[int]) -> list[int]:
        return self.request("POST", "/api/admin/samples/queue-for-annotation",
                            json={"sample_ids": sample_ids}).json()["queued"]

    def predictions(self, round_index: int | None = None) -> dict[str, Any]:
        return self.get_json("/api/admin/exports/predictions", round_index=round_index)

    def set_quality(self, **settings: Any) -> dict[str, Any]:
        """Change the label-quality settings (audit_share, audit_seed, precision_target, min_audits_for_target)."""
        return self.request("PUT", "/api/admin/quality/settings", json=settings).json()

    def quality(self) -> dict[str, Any]:
        return self.get_json("/api/admin/quality")

    def label_audits(self) -> list[dict[str, Any]]:
        return self.get_json("/api/admin/quality/audits")["audits"]

    def mark_gold(self, sample_id: int) -> dict[str, Any]:
        return self.request("POST", "/api/admin/quality/gold", json={"sample_id": sample_id}, expect=(201,)).json()
