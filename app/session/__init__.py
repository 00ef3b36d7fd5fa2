"""Sessions: a manifest's schema (config), its assembly from the readers (assemble) and the frozen
result (model). See app/session/config.py for every manifest key."""

from app.session.assemble import assemble, open_session
from app.session.config import Manifest, SessionConfig, load_manifest, read_config
from app.session.model import COURSE, FILTERS, TRUTH, Session, device_attitude

__all__ = [
    "COURSE",
    "FILTERS",
    "TRUTH",
    "Manifest",
    "Session",
    "SessionConfig",
    "assemble",
    "device_attitude",
    "load_manifest",
    "open_session",
    "read_config",
]
