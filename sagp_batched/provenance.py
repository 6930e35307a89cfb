"""What a run was made from: resolved config, seeds, package versions, git revision."""
from __future__ import annotations

import importlib.metadata
import platform
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

TRACKED_DISTRIBUTIONS = (
    "sagp-batched",
    "torch",
    "numpy",
    "pybullet",
    "open3d-cpu",
    "open3d",
    "pytorch-kinematics",
    "transformers",
    "scikit-learn",
    "httpx",
    "ray",
)

REPO_ROOT = Path(__file__).resolve().parent.parent


def package_versions() -> dict[str, str]:
    versions = {}
    for name in TRACKED_DISTRIBUTIONS:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return versions


def git_revision(repo: Path = REPO_ROOT) -> dict[str, Any]:
    """HEAD commit and whether the working tree differs from it; None values outside a checkout."""
    def run(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    commit = run("rev-parse", "HEAD")
    status = run("status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "dirty": bool(status) if status is not None else None}


def collect(config_dict: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "command": sys.argv,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "packages": package_versions(),
        "git": git_revision(),
        "config": config_dict,
        **extra,
    }
