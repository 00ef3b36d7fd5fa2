"""Sessions: a manifest's schema (config) read by a validating TOML reader (reader), its assembly
from the readers (assemble), the frozen result (model), the camera at any time for one pose
source (camera_track) and several clips on one clock (timeline). See app/session/config.py for
every manifest key."""

from app.session.assemble import assemble, open_session
from app.session.config import SessionConfig, read_config
from app.session.model import COURSE, FILTERS, TRUTH, Session, device_attitude
from app.session.reader import Manifest, load_manifest

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
