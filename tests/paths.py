"""Where the tests find the repository's own files and the shared data beside it, wherever a test
file sits in tests/ (the folders mirror the packages)."""
from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
"""The repository's root (pyproject.toml, clisp/, tools/, docs/)."""
TOOLS = REPO / "tools"
DOCS = REPO / "docs"
SHARED_DATA = REPO.parent / "shared" / "data"
"""../shared/data beside the repository; tests that read it skip where it is absent."""
CAMERA_RAWS = SHARED_DATA / "raw"
