"""Random packet loss on a link without ``netem``: a six-instruction eBPF classifier.

``tc netem loss`` is the usual way to lose packets, but not every kernel has ``sch_netem``
(the Firecracker guest kernel this was developed on has none). ``cls_bpf`` with a
direct-action program is in far more kernels: this one draws ``bpf_get_prandom_u32()`` per
packet and answers ``TC_ACT_SHOT`` (drop) when the draw falls below ``percent`` % of 2³², else
``TC_ACT_OK``. It is loaded with the ``bpf(2)`` system call, pinned on a private ``bpffs``
mount, and attached by ``tc`` to the ``clsact`` egress hook of an interface
(:meth:`twinslam.hosts.netns.NetnsHosts.lose_packets`). Linux x86-64 and arm64, root only.
"""

from __future__ import annotations

import ctypes
import os
import platform
import struct
from pathlib import Path

SYS_BPF = {"x86_64": 321, "aarch64": 280}
BPF_PROG_LOAD, BPF_OBJ_PIN = 5, 6
BPF_PROG_TYPE_SCHED_CLS = 3
HELPER_GET_PRANDOM_U32 = 7
TC_ACT_OK, TC_ACT_SHOT = 0, 2
ATTR_SIZE = 128                         #: bytes of union bpf_attr we pass (zero-padded)


class EbpfError(OSError):
    """The kernel refused the program or the pin (the message holds its reason)."""


def _insn(code: int, dst: int = 0, src: int = 0, off: int = 0, imm: int = 0) -> bytes:
    return struct.pack("<BBhi", code, (src << 4) | dst, off, imm)


def random_drop_program(percent: float) -> bytes:
    """The classifier's bytecode: drop with probability ``percent`` / 100 (0 ≤ p < 50)."""
    if not 0 <= percent < 50:
        raise ValueError(f"loss must be in [0, 50) %, got {percent}")
    threshold = int(percent / 100 * 2**32)
    return b"".join([
        _insn(0x85, imm=HELPER_GET_PRANDOM_U32),       # r0 = bpf_get_prandom_u32()
        _insn(0x25, dst=0, off=2, imm=threshold),       # if r0 > threshold goto pass
        _insn(0xB7, dst=0, imm=TC_ACT_SHOT),            # r0 = drop
        _insn(0x95),                                    # exit
        _insn(0xB7, dst=0, imm=TC_ACT_OK),              # pass: r0 = ok
        _insn(0x95),                                    # exit
    ])


def _bpf(cmd: int, attr: ctypes.Array[ctypes.c_char]) -> int:
    number = SYS_BPF.get(platform.machine())
    if number is None:
        raise EbpfError(f"no bpf(2) system call number known for {platform.machine()}")
    libc = ctypes.CDLL(None, use_errno=True)
    result = libc.syscall(number, cmd, attr, ATTR_SIZE)
    if result < 0:
        err = ctypes.get_errno()
        raise EbpfError(err, f"bpf(cmd {cmd}) failed: {os.strerror(err)}")
    return int(result)


def pin_random_drop(percent: float, pin_path: Path) -> None:
    """Load the program and pin it at ``pin_path`` (on a mounted ``bpffs``)."""
    code = random_drop_program(percent)
    insns = ctypes.create_string_buffer(code, len(code))
    license_ = ctypes.create_string_buffer(b"GPL")
    log = ctypes.create_string_buffer(4096)
    attr = ctypes.create_string_buffer(ATTR_SIZE)
    struct.pack_into("<IIQQIIQ", attr, 0, BPF_PROG_TYPE_SCHED_CLS, len(code) // 8,
                     ctypes.addressof(insns), ctypes.addressof(license_), 1, len(log),
                     ctypes.addressof(log))
    try:
        fd = _bpf(BPF_PROG_LOAD, attr)
    except EbpfError as exc:
        raise EbpfError(f"{exc}; verifier: {log.value.decode(errors='replace').strip()}"
                        ) from None
    try:
        path = ctypes.create_string_buffer(str(pin_path).encode())
        pin = ctypes.create_string_buffer(ATTR_SIZE)
        struct.pack_into("<QI", pin, 0, ctypes.addressof(path), fd)
        _bpf(BPF_OBJ_PIN, pin)
    finally:
        os.close(fd)
