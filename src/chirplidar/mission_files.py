"""The mission files that come with the source checkout (``missions/``), found by name."""

from __future__ import annotations

from pathlib import Path


def default_mission_path(name: str = "thesis_bench.toml") -> Path:
    """``missions/<name>`` from the working directory, else from the source checkout."""
    candidates = [
        Path.cwd() / "missions" / name,
        Path(__file__).resolve().parents[2] / "missions" / name,
    ]
    for path in candidates:
        if path.is_file():
            return path
    return candidates[0]  # load_mission reports it as missing, naming the path
