"""A fault of the machine — a full disk or quota, a read-only file system, a folder visphy may
not write — is told apart from a scene's fault and from a bug, and said in one line naming the
path, what was free and needed (exit status 74). The full-disk run that resumes is in
test_resume.py."""

from __future__ import annotations

import errno
import os
import subprocess
import sys

from conftest import REPO
from visphy_core.infra.errors import HostFault, describe_host_fault, host_fault


def test_a_host_fault_is_found_anywhere_in_the_chain_and_only_for_files():
    full = OSError(errno.ENOSPC, "No space left on device")
    try:
        try:
            raise full
        except OSError as exc:
            raise RuntimeError("encoding the clip failed") from exc
    except RuntimeError as wrapped:
        assert host_fault(wrapped) is full
    assert host_fault(RuntimeError("a bug")) is None
    assert host_fault(OSError(errno.ENOENT, "gone", "/x")) is None
    # a refused namespace or signal (no file) is the sandbox's, not the machine's
    assert host_fault(PermissionError(errno.EPERM, "Operation not permitted")) is None
    denied = PermissionError(errno.EACCES, "Permission denied", "/srv/runs")
    assert host_fault(denied) is denied


def test_each_fault_is_one_line_naming_the_path_and_what_to_do(tmp_path):
    full = OSError(errno.ENOSPC, "No space left on device")
    full.visphy_path, full.visphy_needed = str(tmp_path / "runs" / "summary.json"), 3 * 2**20
    line = describe_host_fault(full)
    assert line.startswith(f"disk full writing {tmp_path}/runs/summary.json (")
    assert " free there, about 3.0 MB needed)" in line
    quota = describe_host_fault(OSError(errno.EDQUOT, "Disk quota exceeded", str(tmp_path)))
    assert quota.startswith("disk quota exceeded writing")
    assert describe_host_fault(OSError(errno.EROFS, "Read-only", "/ro/x")) == \
        "read-only file system: cannot write /ro/x"
    denied = describe_host_fault(PermissionError(errno.EACCES, "Permission denied", "/srv/r"))
    assert denied.startswith("permission denied writing /srv/r: set VISPHY_HOME")
    assert all("\n" not in text for text in (line, quota, denied))
    assert HostFault.exit_code == 74


def test_a_home_visphy_may_not_write_is_one_line_and_status_74():
    """``VISPHY_HOME`` under sysfs, where nobody (root included) may create a folder."""
    env = dict(os.environ, VISPHY_HOME="/sys/kernel/visphy-home")
    done = subprocess.run([sys.executable, "-m", "visphy_core", "model=oracle", "dataset=mini",
                           "tracking=none"], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 74, done.stderr[-2000:]
    assert done.stderr.strip().splitlines() == [
        "error: permission denied writing /sys/kernel/visphy-home: set VISPHY_HOME (or "
        "paths.root) to a folder you can write, or fix its permissions; then rerun the same "
        "command"]
