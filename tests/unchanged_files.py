"""The content hash of each file under a path, to state that files a command must leave alone
(a user's inputs, an earlier run's artifacts) are byte for byte what they were."""

from __future__ import annotations

import hashlib
from pathlib import Path


def tree_hashes(path: Path) -> dict[str, str]:
    """{path relative to ``path``'s parent: sha256} of ``path`` (a file) or of every file under
    it (a folder)."""
    path = Path(path)
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    # exact same-run: files left alone, or written by runs here
    return {str(p.relative_to(path.parent)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in files}
