"""``scripts/run exec`` runs in the caller's directory, so a user's relative paths are theirs."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_exec_runs_in_the_callers_directory(tmp_path: Path) -> None:
    (tmp_path / "my_bag").mkdir()
    env = dict(os.environ)
    out = subprocess.run(
        ["bash", str(REPO / "scripts" / "run"), "exec", "python", "-c",
         "import os, twotank_validation; print(os.getcwd()); print(os.path.isdir('my_bag'))"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    cwd, found = out.stdout.split()[-2:]
    assert Path(cwd).resolve() == tmp_path.resolve()
    assert found == "True"
