"""Settings from the environment (prefix HANDLOOP_) or a .env file, one typed class for all processes."""

from __future__ import annotations

import logging
import os
import secrets
import stat
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

logger = logging.getLogger(__name__)

# Keys once published as defaults (anyone can sign tokens with them): refused in every environment.
PUBLISHED_SECRET_KEYS = frozenset({"change-me-in-production"})
SECRET_KEY_FILE = "secret_key"


class Settings(BaseSettings):
    """handloop's configuration. Every field can be set as HANDLOOP_<FIELD_NAME>."""

    model_config = SettingsConfigDict(env_prefix="HANDLOOP_", env_file=".env", extra="ignore")

    data_dir: Path = Field(default=Path("data"), description="Root for captures, uploads, caches, exports.")
    mano_path: Path | None = Field(
        default=None,
        description="Your licensed MANO_RIGHT.pkl (or a folder holding MANO_RIGHT.pkl / MANO_LEFT.pkl). "
        "Unset: the built-in procedural stand-in hand is used.",
    )
    render_width_px: int = Field(default=320, ge=32, le=4096, description="Working image width for synthesis.")
    torch_threads: int = Field(default=0, ge=0, le=256, description="torch intra-op threads; 0 = torch default.")

    # --- backend service -------------------------------------------------------------------------
    environment: Literal["development", "test", "production"] = Field(
        default="development", description="Deployment kind (logging, checks); no behaviour depends on it silently."
    )
    database_url: str | None = Field(
        default=None,
        description="SQLAlchemy URL, e.g. postgresql+psycopg://user@host/db. Unset: SQLite file "
        "<data_dir>/handloop.sqlite3.",
    )
    # A fixed pool as large as the old pool + overflow (10 + 20): the same connections at most, and the same wait
    # beyond them, but an overflow connection was closed when given back to a full pool, so a load above 10
    # requests in flight opened a PostgreSQL session (a backend planning its statements again) per request
    # (docs/benchmarks.md, api, 2026-12-04).
    db_pool_size: int = Field(default=30, ge=1, le=200, description="Database connections per server process "
                              "(PostgreSQL), opened as needed and kept; a request beyond them waits for one.")
    db_max_overflow: int = Field(default=0, ge=0, le=500, description="Extra connections beyond the pool, each "
                                 "closed when it is given back to a full pool: under a sustained load above the pool, "
                                 "a new PostgreSQL session per request.")
    secret_key: str | None = Field(
        default=None, min_length=16, description="Signs access tokens and scene tickets. Unset: a random key made "
        "once and kept in <data_dir>/secret_key (mode 0600), shared by every process using that folder.")
    access_token_minutes: int = Field(default=12 * 60, ge=1, le=60 * 24 * 30, description="Token lifetime.")
    auth_cache_seconds: float = Field(
        default=2.0, ge=0, le=60, description="How long a server process reuses a token's user row (0: read it on "
        "every request). A revoked token stops working at once in the process that revoked it, within this time in "
        "the others.")
    login_max_failures_per_account: int = Field(
        default=5, ge=1, le=10_000, description="Failed logins per account within login_failure_window_s; then that "
        "account's logins (even with the right password) are refused with 429 until the oldest failure expires.")
    login_max_failures_per_address: int = Field(
        default=30, ge=1, le=1_000_000, description="Failed logins per client address within the window; then that "
        "address's logins are refused with 429.")
    login_failure_window_s: float = Field(default=900.0, gt=0, le=7 * 24 * 3600,
                                          description="How long a failed login counts against its account and address.")
    import_roots: list[Path] = Field(
        default_factory=list, max_length=100, description="Folders `POST /api/admin/imports` may import captures "
        "from (the capture folder must lie inside one, symbolic links resolved). Empty: <data_dir>/captures. As JSON "
        "in the environment: HANDLOOP_IMPORT_ROOTS='[\"/srv/captures\"]'. The CLI's `handloop import` is not limited.")
    trusted_proxies: list[str] = Field(
        default_factory=list, max_length=100, description="Addresses (IPs or CIDR networks) of reverse proxies whose "
        "X-Forwarded-For / X-Forwarded-Proto name the client; a request from any other peer (localhost included) is "
        "the connection's own address, whatever its headers say (the per-address login limit counts it). Empty: no "
        "proxy is trusted. As JSON in the environment: HANDLOOP_TRUSTED_PROXIES='[\"10.0.0.2\"]'.")
    login_max_concurrent_hashes: int = Field(
        default=4, ge=1, le=1024, description="Password checks (Argon2, ~260 ms CPU and 64 MiB each) running at once "
        "per server process; further logins wait.")
    login_hash_wait_s: float = Field(default=10.0, ge=0, le=600,
                                     description="How long a login waits for a hashing slot before a 429.")
    max_upload_bytes: int = Field(
        default=8 * 1024 * 1024, ge=1024, le=1024**3, description="Largest accepted request body, bytes."
    )
    max_clicks_per_submission: int = Field(default=21 * 64, ge=1, le=100_000)
    lease_seconds: int = Field(default=300, ge=1, le=24 * 3600, description="How long a queue lease lives.")
    image_cache_seconds: int = Field(default=3600, ge=0, le=365 * 24 * 3600, description="Cache-Control max-age.")
    sse_poll_seconds: float = Field(default=1.0, gt=0, le=60, description="Job progress stream poll interval.")

    # Heuristic verification (paper, "Iterative Refinement"); distances in metres.
    heuristic_min_mean_confidence: float = Field(default=0.8, ge=0, le=1, description="Mean must be above.")
    heuristic_min_keypoint_confidence: float = Field(default=0.6, ge=0, le=1, description="Each at least.")
    heuristic_min_mean_iou: float = Field(default=0.7, ge=0, le=1, description="Mean IoU over views, at least.")
    heuristic_low_iou: float = Field(default=0.5, ge=0, le=1, description="A view below this is 'low'.")
    heuristic_max_low_iou_views: int = Field(default=2, ge=0, le=1000, description="At most this many low views.")
    heuristic_max_mean_distance_m: float = Field(default=0.005, ge=0, le=1, description="Mean 3D distance.")
    heuristic_max_keypoint_distance_m: float = Field(default=0.010, ge=0, le=1, description="Each 3D distance.")
    heuristic_iou_reference: Literal["chroma_key", "handsegnet"] = Field(
        default="chroma_key", description="What a prediction's fit is compared with (its silhouette term and the "
        "heuristic's IoU) per view: 'chroma_key' = on views with a chroma-key mask, that mask cut at MVNet's "
        "predicted wrist (HandSegNet's mask elsewhere); 'handsegnet' = HandSegNet's masks (the paper).")
    # The same three criteria on a pre-annotation's fit, the pretrained detector in MVNet's role: its lifted keypoints'
    # confidences, the fit's IoU with the chroma-key cut, the fit against the lifted keypoints (every keypoint must be
    # lifted). Chosen on tuning seeds 11, 23, 57 (docs/evaluation.md, "The detector's heuristic"); the fit leans on
    # the silhouettes, so it lies further from the lifted points than a fit from MVNet does from MVNet's.
    detector_heuristic: bool = Field(default=True, description="Accept pre-annotation fits by the detector's "
                                     "heuristic (D^h of round 0); off: every detector fit waits for a person.")
    detector_heuristic_min_mean_confidence: float = Field(default=0.5, ge=0, le=1, description="Mean must be above.")
    detector_heuristic_min_keypoint_confidence: float = Field(default=0.0, ge=0, le=1, description="Each at least.")
    detector_heuristic_min_mean_iou: float = Field(default=0.7, ge=0, le=1, description="Mean IoU, at least.")
    detector_heuristic_low_iou: float = Field(default=0.5, ge=0, le=1, description="A view below this is 'low'.")
    detector_heuristic_max_low_iou_views: int = Field(default=1, ge=0, le=1000, description="At most this many.")
    detector_heuristic_max_mean_distance_m: float = Field(default=0.010, ge=0, le=1, description="Mean 3D distance.")
    detector_heuristic_max_keypoint_distance_m: float = Field(default=0.025, ge=0, le=1,
                                                              description="Each 3D distance.")
    # Rounds >= 1: a fit from MVNet's prediction that fails the paper's heuristic (and the check below), judged by
    # the detector's thresholds against the detector's lift its pre-annotation left. MVNet and the detector share
    # no input but the images, so their agreement is evidence the paper's heuristic lacks; docs/evaluation.md.
    cross_heuristic: bool = Field(default=True, description="Accept a fit from MVNet's prediction that agrees with "
                                  "the detector's lift by the detector's heuristic thresholds; off: only the paper's.")
    # Stricter than the detector's 10 mm: on tuning seed 11 the two fits it let through over 10 mm lay 8.8-8.9 mm
    # from the lift (docs/evaluation.md, "Cross-estimator checks").
    cross_heuristic_max_mean_distance_m: float = Field(default=0.008, ge=0, le=1, description="Mean 3D distance of "
                                                       "MVNet's fit from the lift, at most.")
    # Rounds >= 1, checked first: the pre-annotation's own fit judged by the paper's criteria with MVNet's
    # prediction as the estimate; passing, the sample is accepted with that fit (workers.tasks.cross_checks). Chosen
    # on tuning seeds 11 and 57, then judged by the matrix: on unseen seed 7741, 3 of its 5 accepts were over 10 mm
    # (lifts of mean confidence 0.48, just under the detector's 0.5), so it is off until re-chosen on tuning seeds
    # (docs/evaluation.md, "Cross-estimator checks").
    earlier_fit_check: bool = Field(default=False, description="Accept a sample with its pre-annotation's fit when "
                                    "MVNet's prediction agrees with it (off by default: it failed the precision "
                                    "target on an unseen capture); off: never.")
    earlier_fit_check_min_mean_confidence: float = Field(default=0.5, ge=0, le=1, description="Mean must be above.")
    earlier_fit_check_min_keypoint_confidence: float = Field(default=0.0, ge=0, le=1, description="Each at least.")
    earlier_fit_check_min_mean_iou: float = Field(default=0.6, ge=0, le=1, description="Mean IoU, at least.")
    earlier_fit_check_low_iou: float = Field(default=0.5, ge=0, le=1, description="A view below this is 'low'.")
    earlier_fit_check_max_low_iou_views: int = Field(default=2, ge=0, le=1000, description="At most this many.")
    earlier_fit_check_max_mean_distance_m: float = Field(default=0.008, ge=0, le=1, description="Mean 3D distance.")
    earlier_fit_check_max_keypoint_distance_m: float = Field(default=1.0, ge=0, le=1,
                                                             description="Each 3D distance (1 m: no limit).")
    earlier_fit_check_min_lift_confidence: float = Field(default=0.4, ge=0, le=1, description="The detector's lift "
                                                         "the earlier fit was made from: mean confidence above.")
    # Rounds >= 1: where no heuristic took MVNet's fit, the reviewers see the pre-annotation's fit instead (no person
    # decided on it). Offline on tuning seeds 11 and 57, of the 10-13 MVNet fits reviewed in rounds 1-2 that had one,
    # the pre-annotation's fit was within the reviewers' 8 mm for 7-9, MVNet's for 4-6. Off until the matrix judges it.
    review_pre_annotation_fit: bool = Field(default=False, description="Show reviewers the sample's pre-annotation "
                                            "fit where no heuristic took MVNet's fit (rounds 1 on); off: MVNet's fit.")

    # Reviewer queue policy (paper, "Manual Verification and Annotation").
    review_min_confidence_percentile: float = Field(default=50.0, ge=0, le=100)
    review_min_time_gap_s: float = Field(
        default=1.0, ge=0, le=3600, description="Minimal time between frames picked from one sequence."
    )
    review_min_pose_distance: float = Field(
        default=0.5, ge=0, le=100, description="Minimal Euclidean norm of the articulation from the flat hand."
    )
    review_max_batch: int = Field(default=1000, ge=1, le=1_000_000, description="Most samples queued per build.")
    review_capacity_per_round: int = Field(
        default=0, ge=0, le=1_000_000, description="Samples the reviewers can verify in a round (the paper "
        "verified 1,000 in its first): the queue is filled to it with the candidates ranked by confidence, the time "
        "gap only ordering them, the percentile a floor or an order (review_percentile_cut; docs/evaluation.md, "
        "'The review queue'). Samples already in review count against it. 0 (the default until the sim-matrix "
        "measures the capacity policy on unseen seeds: on quick plans it added 3x the labels at fewer labels per "
        "human hour at 320 px): the fixed policy (percentile cut and time gap as filters).")
    preannotation_review_capacity: int | None = Field(
        default=None, ge=0, le=1_000_000, description="Round 0's own review capacity: the detector's fits the "
        "reviewers can verify in the pre-annotation (0: the fixed policy), ranked as `review_capacity_per_round` "
        "ranks; unset (the default): as the later rounds (review_capacity_per_round). The matrix measured 1000: a "
        "larger D_0 but fewer labels per human hour on each unseen seed (docs/evaluation.md, 'The review queue').")
    review_rank: Literal["confidence", "agreement"] = Field(
        default="confidence", description="What rounds 1 on rank the fits from predictions by for review (the "
        "percentile and the order): 'confidence', MVNet's mean confidence (the paper's); 'agreement', how close the "
        "fit came to the prediction it was fitted to (the heuristic's mean 3D distance). On tuning seeds 57 and 23 "
        "the confidence of MVNet trained on D_0 did not rank the fits' true error (Spearman -0.27, -0.06), the "
        "agreement did (0.85, 0.87); the sim-matrix judges it on unseen seeds (docs/evaluation.md, 'The review "
        "queue').")
    review_percentile_cut: bool = Field(
        default=True, description="With a capacity, rounds 1 on: the queue is filled only from the confidence "
        "percentile up (the rest waits for the next round's networks: a fit sent back costs an annotation); false: "
        "the percentile only orders the candidates. Round 0's detector fits are all offered until the detector's "
        "heuristic has given D_0 round_min_training_samples labels.")

    # --- workers: Celery broker, job hand-off and robustness (docs/deployment.md) -----------------
    broker_url: str | None = Field(
        default=None, description="Celery broker, e.g. redis://host:6379/0 (distributed mode). Unset: the embedded "
        "broker, kombu's filesystem transport under <data_dir>/broker (no server needed).")
    result_backend_url: str | None = Field(
        default=None, description="Celery result backend (only chords use it; job state lives in the database). "
        "Unset: the Redis broker's server, or files under <data_dir>/broker/results in embedded mode.")
    broker_prefix: str = Field(
        default="", max_length=100, description="Prefix of every Redis key (several deployments on one server).")
    broker_visibility_timeout_s: int = Field(
        default=4 * 3600, ge=2, le=7 * 24 * 3600, description="Redis: an unacknowledged task is redelivered after "
        "this long; must exceed the longest task (task_time_limit_s).")
    broker_check_cache_s: float = Field(
        default=2.0, ge=0, le=3600, description="The API trusts a successful broker check for this long before "
        "writing jobs (an unreachable broker answers 503 and writes nothing).")
    fit_dispatch_linger_s: float = Field(
        default=0.25, ge=0, le=10, description="The API sends annotators' fit jobs to the broker several per message: "
        "it waits this long for more (at most fit_batch_size) before sending. A publish costs the API about as much "
        "CPU as the rest of a submission; a fit takes seconds, so a quarter of a second more is not seen.")
    outbox_poll_s: float = Field(
        default=2.0, gt=0, le=3600, description="How often the API re-sends jobs whose hand-off to the broker failed.")
    job_redispatch_after_s: float = Field(
        default=1800.0, ge=1, le=7 * 24 * 3600, description="A job still 'queued' this long after its hand-off is "
        "sent again (a broker that lost it); tasks are idempotent, so a duplicate does nothing.")
    job_heartbeat_timeout_s: float = Field(
        default=120.0, ge=1, le=24 * 3600, description="A 'running' job whose row has not changed for this long "
        "belongs to a dead worker: a redelivered task takes it over, and the outbox re-sends it.")
    job_max_attempts: int = Field(
        default=3, ge=1, le=100, description="A job started this many times without finishing (its worker died or "
        "it crashed) fails instead of running again.")
    task_time_limit_s: int = Field(
        default=3 * 3600, ge=10, le=7 * 24 * 3600, description="Hard time limit of the longest tasks (training, "
        "whole rounds' steps); the soft limit is 90 % of it.")
    fit_task_time_limit_s: int = Field(
        default=1800, ge=5, le=24 * 3600, description="Hard time limit of one fit or prediction batch task.")
    worker_concurrency: int = Field(default=1, ge=1, le=256, description="Worker processes per `handloop worker`.")
    worker_torch_threads: int = Field(default=1, ge=1, le=256, description="torch threads in each worker process.")

    # --- bootstrap rounds (sized for a 2-core CPU; the paper's sizes are the 'paper' nets on a GPU) ------
    nets_config: Literal["tiny", "cpu-small", "paper"] = Field(
        default="cpu-small", description="Network configuration trained in each round (workers/nets/configs.py).")
    mvnet_detector: bool = Field(
        default=True, description="Rounds train and run the detector-backed MVNet (the pretrained detector's "
        "keypoints in place of the learned 2D head: '<nets_config>-detector') where the detector's model files are "
        "installed and such a configuration exists; off, or without the files, the paper-only MVNet.")
    round_handsegnet_budget_s: float = Field(default=90.0, gt=0, le=7 * 24 * 3600,
                                             description="HandSegNet training seconds per round.")
    round_mvnet_budget_s: float = Field(default=240.0, gt=0, le=7 * 24 * 3600,
                                        description="MVNet training seconds per round.")
    round_max_train_steps: int | None = Field(default=None, ge=1, description="Optional step cap per network.")
    round_handsegnet_max_steps: int | None = Field(
        default=None, ge=1, description="Optional step cap of HandSegNet alone, in place of round_max_train_steps "
        "(to compare HandSegNet's training with MVNet's held fixed).")
    round_min_training_samples: int = Field(default=2, ge=1, le=1_000_000,
                                            description="A round needs at least this many accepted samples.")
    round_seed: int = Field(default=0, ge=0, description="Seeds training (plus the round index).")
    predict_batch_size: int = Field(default=16, ge=1, le=4096, description="Samples per prediction task.")
    fit_batch_size: int = Field(default=6, ge=1, le=512, description="Samples per fit task: a round's batches, "
                                "and at most this many annotators' fits sent together.")
    fit_optimizer: Literal["levenberg_marquardt", "adam"] = Field(
        default="levenberg_marquardt", description="Levenberg-Marquardt (default; stops when converged) or the "
        "paper's gradient descent (Adam: always runs its iterations, much slower).")
    fit_global_iterations: int = Field(default=12, ge=1, le=100_000,
                                       description="Fit stage 1: most solver steps (Adam: its steps).")
    fit_full_iterations: int = Field(default=30, ge=0, le=100_000,
                                     description="Fit stage 2: most solver steps (Adam: its steps).")
    preannotate_on_import: bool = Field(
        default=False, description="After an import, run the pretrained detector -> triangulation -> fit on its "
        "samples (round 0 without clicks); refused, and the import is as without it, where the detector is missing.")

    @model_validator(mode="after")
    def _refuse_published_secret(self) -> Settings:
        if self.secret_key in PUBLISHED_SECRET_KEYS:
            raise ValueError("HANDLOOP_SECRET_KEY is a published default: anyone could sign tokens with it; set a "
                             "random one (e.g. `openssl rand -hex 32`) or unset it to use <data_dir>/secret_key")
        return self

    @model_validator(mode="after")
    def _visibility_above_longest_task(self) -> Settings:
        longest = max(self.task_time_limit_s, self.fit_task_time_limit_s)
        if self.broker_visibility_timeout_s <= longest:
            raise ValueError(f"broker_visibility_timeout_s ({self.broker_visibility_timeout_s}) must exceed the "
                             f"longest task time limit ({longest} s), or a running task would be delivered twice")
        return self

    @cached_property
    def signing_key(self) -> str:
        """The key that signs tokens: HANDLOOP_SECRET_KEY, else the data folder's own random key (made on first
        use). Read lazily, so commands that sign nothing leave the data folder alone."""
        if self.secret_key is not None:
            return self.secret_key
        return data_dir_secret(self.data_dir / SECRET_KEY_FILE)

    @property
    def allowed_import_roots(self) -> list[Path]:
        """Where the API imports captures from (import_roots, else <data_dir>/captures), symbolic links resolved."""
        return [Path(p).resolve() for p in (self.import_roots or [self.data_dir / "captures"])]

    @property
    def broker_dir(self) -> Path:
        """The embedded broker's folders (kombu filesystem transport) and file result backend."""
        return self.data_dir / "broker"

    @property
    def checkpoints_dir(self) -> Path:
        """Network checkpoints, one folder per round (workers/nets/checkpoints.py round_dir)."""
        return self.data_dir / "checkpoints"

    @property
    def cache_dir(self) -> Path:
        return self.data_dir / "cache"

    @property
    def storage_dir(self) -> Path:
        return self.data_dir / "storage"

    @property
    def resolved_database_url(self) -> str:
        """The database URL, defaulting to a SQLite file in the data directory."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'handloop.sqlite3').resolve()}"


def data_dir_secret(path: Path) -> str:
    """The random key kept in `path`, made once (32 random bytes, URL-safe base64, mode 0600).

    Several processes may start at once (the demo's API and worker): each writes its own candidate to a
    temporary file and links it into place; `os.link` fails if another process got there first, and then
    that process's key is read, so all of them sign with the same key. An existing file is never replaced
    (that would log everybody out); an empty or short one is an error that names the file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists():
        candidate = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}")
        fd = os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            with os.fdopen(fd, "w") as out:
                out.write(secrets.token_urlsafe(32) + "\n")
                out.flush()
                os.fsync(out.fileno())
            try:
                os.link(candidate, path)
                logger.info("made a random secret key in %s", path)
            except FileExistsError:
                pass  # another process made it first: use theirs
        finally:
            candidate.unlink(missing_ok=True)
    mode = stat.S_IMODE(path.stat().st_mode)
    if mode & 0o077:
        logger.warning("%s is readable by other users (mode %o); anyone who can read it can sign tokens", path, mode)
    key = path.read_text(encoding="ascii").strip()
    if len(key) < 16:
        raise ValueError(f"{path} holds no usable secret key (fewer than 16 characters): delete it to make a new "
                         "one (every signed-in user must log in again) or set HANDLOOP_SECRET_KEY")
    return key


@lru_cache
def get_settings() -> Settings:
    return Settings()
