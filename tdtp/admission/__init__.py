"""A slave's front door: address-validation cookies, OPEN rate limits and key checks, before any
per-session state exists (docs/PROTOCOL.md section 5.1)."""

from tdtp.admission.admission import Admission, AdmissionStats, AdmittedOpen, Reply
from tdtp.admission.cookie import CookieJar
from tdtp.admission.path_migration import MigrationStats, PathMigration
from tdtp.admission.rate_limit import SourceRateLimiter, TokenBucket

__all__ = [
    "Admission",
    "AdmissionStats",
    "AdmittedOpen",
    "CookieJar",
    "MigrationStats",
    "PathMigration",
    "Reply",
    "SourceRateLimiter",
    "TokenBucket",
]
