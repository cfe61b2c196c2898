"""The seccomp filter of the sandboxes: system calls a model-written program never needs and that
only widen the kernel surface it can reach (namespaces, tracing, mounts, keyrings, BPF, perf,
userfaultfd, io_uring, module and kexec loading).

The filter is built with **libseccomp** through its official Python binding (Debian package
``python3-seccomp``, `scripts/setup.sh` installs it), exported as a classic BPF program
(``seccomp_export_bpf``) and handed to bubblewrap (``bwrap --seccomp FD``), which loads it last,
right before it executes the sandboxed command (``setpriv`` and then the program), with
``no_new_privs`` set. Everything not listed is allowed (a deny list: Python, the native
libraries the Python engines render with, and Chromium run unchanged); a listed call fails with
an errno and nothing else happens:

* ``unshare``, ``setns``: any flags, ``EPERM``. ``clone`` with any ``CLONE_NEW*`` bit
  (``NEWNS``, ``NEWCGROUP``, ``NEWUTS``, ``NEWIPC``, ``NEWUSER``, ``NEWPID``, ``NEWNET``):
  ``EPERM``; threads, ``fork``, ``vfork`` and ``posix_spawn`` pass (no such bit).
  ``clone3``: ``ENOSYS`` - its flags live in a struct in memory that seccomp cannot read, and
  ``ENOSYS`` makes glibc (``pthread_create``, ``posix_spawn``) fall back to ``clone``, which is
  filtered. No new namespace of any kind, and in particular no nested user namespace (the only
  way an unprivileged program gets a full capability set).
* ``ptrace``, ``process_vm_readv``, ``process_vm_writev``, ``pidfd_getfd``: ``EPERM``; no
  tracing or reading another process's memory or descriptors (not even the program's own
  children: debuggers do not run in the sandbox).
* ``mount``, ``umount2``, ``pivot_root``, ``chroot``, the new mount API (``open_tree``,
  ``move_mount``, ``fsopen``, ``fsconfig``, ``fsmount``, ``fspick``, ``mount_setattr``):
  ``EPERM``. They need a capability the program does not have; denied anyway as the usual
  next step of a namespace escape.
* ``keyctl``, ``add_key``, ``request_key``: ``EPERM``. Kernel keyrings are not namespaced:
  the user keyring of uid 65534 is shared with every other process of that uid on the host.
* ``bpf``, ``perf_event_open``, ``userfaultfd``, ``io_uring_setup``, ``io_uring_enter``,
  ``io_uring_register``: ``EPERM``. Reachable without a capability on many kernels (depending
  on sysctls), a long record of kernel exploits, and nothing a rendering program uses.
* ``kexec_load``, ``kexec_file_load``, ``init_module``, ``finit_module``, ``delete_module``,
  ``open_by_handle_at``: ``EPERM``. Capability-gated (module/boot/``CAP_DAC_READ_SEARCH``),
  denied as defence in depth.

System calls of another ABI (i386 ``int 0x80``, x32) fail with ``ENOSYS`` (libseccomp's
"bad architecture" action), so the filter cannot be sidestepped through them. The filter is
compiled for the architectures listed in `SUPPORTED_ARCHES` only (where ``clone``'s flags are
its first argument); elsewhere `bpf_program` raises `FilterUnavailable` and the process sandbox
refuses untrusted code like it does without bubblewrap.

Run as a script (``python3 -I syscall_filter.py``), this file writes the BPF program to stdout:
the host uses that, with the system ``python3``, when its own interpreter cannot load the
binding (a venv of another Python version). It imports only the standard library.
"""

from __future__ import annotations

import errno
import functools
import importlib.machinery
import importlib.util
import os
import subprocess
import sys
import tempfile

#: ``clone`` flags that create a namespace (``CLONE_NEWTIME``, 0x80, exists for ``unshare`` and
#: ``clone3`` only: in ``clone`` that byte is the exit signal).
CLONE_NEW_FLAGS = {
    "CLONE_NEWNS": 0x00020000,
    "CLONE_NEWCGROUP": 0x02000000,
    "CLONE_NEWUTS": 0x04000000,
    "CLONE_NEWIPC": 0x08000000,
    "CLONE_NEWUSER": 0x10000000,
    "CLONE_NEWPID": 0x20000000,
    "CLONE_NEWNET": 0x40000000,
}

#: System calls denied outright, with the errno the program sees.
DENIED: dict[str, int] = {
    # namespaces (clone is filtered by its flags, clone3 below)
    "unshare": errno.EPERM, "setns": errno.EPERM,
    # tracing and other processes' memory / descriptors
    "ptrace": errno.EPERM, "process_vm_readv": errno.EPERM, "process_vm_writev": errno.EPERM,
    "pidfd_getfd": errno.EPERM,
    # mounts and root changes
    "mount": errno.EPERM, "umount2": errno.EPERM, "pivot_root": errno.EPERM,
    "chroot": errno.EPERM, "open_tree": errno.EPERM, "move_mount": errno.EPERM,
    "fsopen": errno.EPERM, "fsconfig": errno.EPERM, "fsmount": errno.EPERM,
    "fspick": errno.EPERM, "mount_setattr": errno.EPERM,
    # kernel keyrings (not namespaced)
    "keyctl": errno.EPERM, "add_key": errno.EPERM, "request_key": errno.EPERM,
    # kernel surfaces reachable without capabilities
    "bpf": errno.EPERM, "perf_event_open": errno.EPERM, "userfaultfd": errno.EPERM,
    "io_uring_setup": errno.EPERM, "io_uring_enter": errno.EPERM,
    "io_uring_register": errno.EPERM,
    # capability-gated, defence in depth
    "kexec_load": errno.EPERM, "kexec_file_load": errno.EPERM, "init_module": errno.EPERM,
    "finit_module": errno.EPERM, "delete_module": errno.EPERM,
    "open_by_handle_at": errno.EPERM,
    # flags in memory, not filterable: ENOSYS makes glibc fall back to clone
    "clone3": errno.ENOSYS,
}

#: libseccomp architecture names the filter is built for: ``clone``'s flags are argument 0.
SUPPORTED_ARCHES = ("x86_64", "aarch64")

#: Where Debian's binding lives (``python3-seccomp``), for interpreters outside the system one.
_DIST_PACKAGES = ("/usr/lib/python3/dist-packages",)
#: The system interpreter that has the binding, for the subprocess fallback.
SYSTEM_PYTHON = "/usr/bin/python3"
INSTALL_HINT = ("install libseccomp's Python binding (`apt-get install python3-seccomp`, "
                "scripts/setup.sh)")


class FilterUnavailable(RuntimeError):
    """The seccomp filter cannot be built here (no libseccomp binding, unsupported arch)."""


def _load_binding():
    """libseccomp's Python module: importable as ``seccomp``, else Debian's extension loaded from
    its file when this interpreter's ABI matches it; None when neither works."""
    try:
        import seccomp  # type: ignore[import-not-found]

        return seccomp
    except ImportError:
        pass
    for base in _DIST_PACKAGES:
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = os.path.join(base, "seccomp" + suffix)
            if not os.path.isfile(path):
                continue
            try:
                spec = importlib.util.spec_from_file_location("seccomp", path)
                if spec is None or spec.loader is None:
                    continue
                module = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(module)
                return module
            except (ImportError, OSError):
                continue
    return None


def _arch_name(sc, token: int) -> str:
    for name in dir(sc.Arch):
        value = getattr(sc.Arch, name)
        if (not name.startswith("_") and name != "NATIVE" and isinstance(value, int)
                and value & 0xFFFFFFFF == token & 0xFFFFFFFF):  # the binding mixes signedness
            return name.lower()
    return f"arch-{token & 0xFFFFFFFF:#x}"


def build(sc) -> bytes:
    """The BPF program, built with the libseccomp module ``sc``."""
    arch = _arch_name(sc, sc.system_arch())
    if arch not in SUPPORTED_ARCHES:
        raise FilterUnavailable(f"no seccomp filter for architecture {arch} (supported: "
                                f"{', '.join(SUPPORTED_ARCHES)})")
    filt = sc.SyscallFilter(sc.ALLOW)
    # another ABI's system calls (i386 int 0x80, x32): fail, never run unfiltered
    filt.set_attr(sc.Attr.ACT_BADARCH, sc.ERRNO(errno.ENOSYS))
    for name, err in DENIED.items():
        filt.add_rule(sc.ERRNO(err), name)
    for bit in CLONE_NEW_FLAGS.values():
        filt.add_rule(sc.ERRNO(errno.EPERM), "clone", sc.Arg(0, sc.MASKED_EQ, bit, bit))
    with tempfile.TemporaryFile() as fh:
        filt.export_bpf(fh)
        fh.seek(0)
        program = fh.read()
    if not program or len(program) % 8:
        raise FilterUnavailable(f"libseccomp exported {len(program)} bytes of BPF")
    return program


def _build_with_system_python() -> bytes:
    if not os.access(SYSTEM_PYTHON, os.X_OK):
        raise FilterUnavailable(f"libseccomp's Python binding is not importable and "
                                f"{SYSTEM_PYTHON} is missing; {INSTALL_HINT}")
    try:
        proc = subprocess.run([SYSTEM_PYTHON, "-I", os.path.abspath(__file__)],
                              capture_output=True, timeout=60, env={"PATH": "/usr/bin:/bin"},
                              cwd="/")
    except (OSError, subprocess.SubprocessError) as exc:
        raise FilterUnavailable(f"building the seccomp filter with {SYSTEM_PYTHON} failed: "
                                f"{exc}") from exc
    if proc.returncode != 0 or not proc.stdout or len(proc.stdout) % 8:
        why = proc.stderr.decode(errors="replace").strip().splitlines()
        raise FilterUnavailable(f"building the seccomp filter with {SYSTEM_PYTHON} failed: "
                                f"{why[-1] if why else f'exit {proc.returncode}'}")
    return proc.stdout


@functools.lru_cache(maxsize=1)
def _cached() -> bytes | FilterUnavailable:
    sc = _load_binding()
    try:
        return build(sc) if sc is not None else _build_with_system_python()
    except FilterUnavailable as exc:
        return exc
    except Exception as exc:  # the binding raises OSError/RuntimeError/ValueError
        return FilterUnavailable(f"libseccomp could not build the filter: {exc!r}")


def bpf_program() -> bytes:
    """The compiled filter (classic BPF, for ``bwrap --seccomp``), built once per process.
    Raises `FilterUnavailable` with the reason when it cannot be built here."""
    got = _cached()
    if isinstance(got, FilterUnavailable):
        raise got
    return got


def available() -> tuple[bool, str]:
    """(True, "") when the filter can be built here, else (False, why)."""
    try:
        bpf_program()
    except FilterUnavailable as exc:
        return False, str(exc)
    return True, ""


def memfd() -> int:
    """A read-only-use descriptor holding the BPF program at offset 0 (close-on-exec: pass it
    with ``pass_fds``). bwrap reads it to the end."""
    program = bpf_program()
    fd = os.memfd_create("visphy-seccomp", getattr(os, "MFD_CLOEXEC", 1))
    try:
        view = memoryview(program)
        while view:
            view = view[os.write(fd, view):]
        os.lseek(fd, 0, os.SEEK_SET)
    except BaseException:
        os.close(fd)
        raise
    return fd


if __name__ == "__main__":  # python3 -I syscall_filter.py > filter.bpf
    binding = _load_binding()
    if binding is None:
        sys.exit(f"libseccomp's Python binding is not installed; {INSTALL_HINT}")
    try:
        sys.stdout.buffer.write(build(binding))
    except FilterUnavailable as exc:
        sys.exit(str(exc))
