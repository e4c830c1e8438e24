"""Run a command whose statx, faccessat2, openat2 and clone3 system calls fail with ENOSYS.

    python3 scripts/_enosys_exec.py COMMAND [ARGS...]

The armhf test environment (scripts/_env.sh, setup_env armhf) runs Debian's armhf
userland under ``proot -q qemu-arm-static``. proot 5.1 does not translate these four
newer system calls (it passes their paths to the host unchanged), and armhf glibc 2.36
and qemu use them first. Answered ENOSYS, glibc and qemu fall back to the older calls
(fstatat64/newfstatat, faccessat, openat, clone) that proot does translate.

The filter is a seccomp-BPF program installed with prctl through ctypes (no compiler,
no libseccomp); it is inherited across fork and execve by proot, qemu and everything
they run. Every other system call, and every call from another architecture, is allowed.
"""
from __future__ import annotations

import ctypes
import errno
import os
import platform
import struct
import sys

PR_SET_NO_NEW_PRIVS = 38
PR_SET_SECCOMP = 22
SECCOMP_MODE_FILTER = 2
SECCOMP_RET_ALLOW = 0x7FFF0000
SECCOMP_RET_ERRNO = 0x00050000

BPF_LD_W_ABS = 0x20  # BPF_LD | BPF_W | BPF_ABS
BPF_JEQ_K = 0x15  # BPF_JMP | BPF_JEQ | BPF_K
BPF_RET_K = 0x06  # BPF_RET | BPF_K

# struct seccomp_data: int nr; __u32 arch; ...
OFFSET_NR = 0
OFFSET_ARCH = 4

# machine -> (AUDIT_ARCH_*, {name: number}) for the host that runs proot.
ARCHES = {
    "x86_64": (0xC000003E, {"statx": 332, "faccessat2": 439, "openat2": 437, "clone3": 435}),
    "aarch64": (0xC00000B7, {"statx": 291, "faccessat2": 439, "openat2": 437, "clone3": 435}),
}


def _insn(code: int, jt: int, jf: int, k: int) -> bytes:
    return struct.pack("HBBI", code, jt, jf, k)


def build_filter(audit_arch: int, numbers: list[int]) -> bytes:
    n = len(numbers)
    prog = [
        _insn(BPF_LD_W_ABS, 0, 0, OFFSET_ARCH),
        # Another architecture (e.g. an x32 or i386 process): allow, jump past the checks.
        _insn(BPF_JEQ_K, 0, n + 1, audit_arch),
        _insn(BPF_LD_W_ABS, 0, 0, OFFSET_NR),
    ]
    for i, nr in enumerate(numbers):
        # Match: jump to the ERRNO return, which follows the ALLOW one.
        prog.append(_insn(BPF_JEQ_K, n - i, 0, nr))
    prog.append(_insn(BPF_RET_K, 0, 0, SECCOMP_RET_ALLOW))
    prog.append(_insn(BPF_RET_K, 0, 0, SECCOMP_RET_ERRNO | errno.ENOSYS))
    return b"".join(prog)


class _SockFprog(ctypes.Structure):
    _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.c_void_p)]


def install() -> None:
    machine = platform.machine()
    if machine not in ARCHES:
        sys.exit(f"_enosys_exec.py: no syscall table for host architecture {machine!r}")
    audit_arch, table = ARCHES[machine]
    code = build_filter(audit_arch, list(table.values()))
    buf = ctypes.create_string_buffer(code, len(code))
    prog = _SockFprog(len(code) // 8, ctypes.cast(buf, ctypes.c_void_p))
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_void_p, ctypes.c_ulong, ctypes.c_ulong]
    if libc.prctl(PR_SET_NO_NEW_PRIVS, 1, None, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_NO_NEW_PRIVS)")
    if libc.prctl(PR_SET_SECCOMP, SECCOMP_MODE_FILTER, ctypes.addressof(prog), 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_SECCOMP)")


def main(argv: list[str]) -> None:
    if not argv:
        sys.exit(__doc__)
    install()
    os.execvp(argv[0], argv)


if __name__ == "__main__":
    main(sys.argv[1:])
