"""All tables; importing this package registers them on Base.metadata (Alembic relies on it)."""

from backend.models.agreement import AgreementPair
from backend.models.audit import AuditEvent
from backend.models.capture import CameraCalibration, Project, Sample, Sequence, Subject, View
from backend.models.drafts import Draft
from backend.models.enums import (
    DecisionKind,
    FlagKind,
    JobKind,
    JobState,
    LeaseKind,
    MaskKind,
    Role,
    RoundState,
    SampleState,
    Split,
    Stream,
    Visibility,
)
from backend.models.fits import Fit, Prediction
from backend.models.flags import AnnotationFlag
from backend.models.guidelines import Guidelines
from backend.models.jobs import Job
from backend.models.label_audit import GoldLabel, LabelAudit, QualitySettings
from backend.models.labels import Click, Mask, Submission
from backend.models.review import Decision, Round, RoundMember
from backend.models.users import User

__all__ = [
    "AgreementPair",
    "AnnotationFlag", "AuditEvent", "CameraCalibration", "Click", "Decision", "DecisionKind", "Draft", "Fit",
    "FlagKind", "GoldLabel", "Guidelines", "Job", "JobKind", "JobState", "LabelAudit", "LeaseKind", "Mask", "MaskKind",
    "Prediction", "Project", "QualitySettings", "Role", "Round", "RoundMember", "RoundState", "Sample",
    "SampleState", "Sequence", "Split", "Stream", "Subject", "Submission", "User", "View", "Visibility",
]  # fmt: skip
