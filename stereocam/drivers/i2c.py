"""The narrow I2C interface of the sensor drivers, and its Linux implementation.

A sensor driver is handed an :class:`I2CBus` (anything with ``read16`` and
``write16``) and its 7-bit address, exactly as an IP driver is handed its
register window: :class:`LinuxI2CBus` on the board, the emulated bus
(:class:`stereocam.overlays.emulated.i2c.EmulatedI2CBus`) off it, a
recording double in the tests.

Transactions are those of the MT9V0xx sensors (8-bit register address,
16-bit big-endian data), the same as Linux's
``i2c_smbus_{read,write}_word_swapped`` used by the kernel's mt9v032 driver:

* write: ``S addr+W reg hi lo P`` (one message of three bytes);
* read: ``S addr+W reg Sr addr+R hi lo P`` (a write message and a read
  message in one ``I2C_RDWR`` ioctl: a repeated start, no stop between).

Errors: a device that does not acknowledge raises :class:`I2CNack`, an
adapter that gives up raises :class:`I2CTimeout`, anything else from the
kernel :class:`I2CError`; every message names the bus, the address and the
register. Every transaction is bounded by the adapter timeout, which
:class:`LinuxI2CBus` sets when it opens the bus (``I2C_TIMEOUT``).
"""
from __future__ import annotations

import ctypes
import errno
import glob
import math
import os
import threading
from typing import Any, Callable, Optional, Protocol, runtime_checkable

from .mmio import DriverError, RegisterRangeError

__all__ = [
    "I2CBus",
    "I2CDenied",
    "I2CError",
    "I2CNack",
    "I2CTimeout",
    "LinuxI2CBus",
    "check_transaction",
    "nack_error",
]

# <linux/i2c-dev.h> and <linux/i2c.h>
I2C_RETRIES = 0x0701
I2C_TIMEOUT = 0x0702  # argument: timeout in units of 10 ms
I2C_RDWR = 0x0707
I2C_M_RD = 0x0001
I2C_RDWR_IOCTL_MAX_MSGS = 42

ADDRESS_MIN, ADDRESS_MAX = 0x03, 0x77  # 7-bit addresses a device may use (0x00-0x02, 0x78+ reserved)


class I2CError(DriverError):
    """An I2C transaction failed. ``bus``, ``address`` and ``register`` say which (``None`` if unknown)."""

    def __init__(self, message: str, *, bus: str = "", address: Optional[int] = None,
                 register: Optional[int] = None) -> None:
        super().__init__(message)
        self.bus = bus
        self.address = address
        self.register = register


class I2CDenied(I2CError):
    """The bus's device node exists but may not be opened (EPERM/EACCES): not root, or, in a service whose
    device list was made before the i2c-dev driver loaded, not allowed (``DeviceAllow=char-i2c``)."""


class I2CNack(I2CError):
    """No device acknowledged at that address: missing, unpowered, or strapped to another address."""


class I2CTimeout(I2CError):
    """The adapter gave up on the transaction (clock stretched too long or bus stuck)."""


@runtime_checkable
class I2CBus(Protocol):
    """16-bit register access on I2C devices with 8-bit register addresses.

    Both calls block until the transaction is done (bounded by the bus's
    timeout) and raise :class:`I2CError` (or a subclass) on failure.
    Implementations serialise transactions: one bus may serve several
    drivers on several threads.
    """

    def read16(self, address: int, register: int) -> int: ...

    def write16(self, address: int, register: int, value: int) -> None: ...


def check_transaction(address: int, register: int, value: int = 0) -> None:
    """Refuse arguments no 7-bit-address, 8-bit-register, 16-bit-data transaction can carry."""
    for what, v, lo, hi in (("address", address, ADDRESS_MIN, ADDRESS_MAX), ("register", register, 0, 0xFF),
                            ("value", value, 0, 0xFFFF)):
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise RegisterRangeError(f"I2C {what} {v!r} is out of range: {lo:#x}..{hi:#x}")


class _Msg(ctypes.Structure):  # struct i2c_msg
    _fields_ = [("addr", ctypes.c_uint16), ("flags", ctypes.c_uint16), ("len", ctypes.c_uint16),
                ("buf", ctypes.POINTER(ctypes.c_uint8))]


class _RdwrData(ctypes.Structure):  # struct i2c_rdwr_ioctl_data
    _fields_ = [("msgs", ctypes.POINTER(_Msg)), ("nmsgs", ctypes.c_uint32)]


Ioctl = Callable[[int, int, Any], Any]


class LinuxI2CBus:
    """``/dev/i2c-<bus>`` through the i2c-dev ``I2C_RDWR`` ioctl.

    Nothing touches the device until the first transaction (or
    :meth:`open`): constructing one is free and safe off the board.
    ``timeout`` (seconds, rounded up to 10 ms) is written to the adapter
    with ``I2C_TIMEOUT`` on open; note that it applies to the whole adapter.
    ``opener``, ``ioctl`` and ``closer`` default to ``os.open``,
    ``fcntl.ioctl`` and ``os.close`` and exist so tests can check the exact
    messages without hardware. Thread-safe; :meth:`close` is idempotent and
    a later transaction reopens the device.
    """

    def __init__(self, bus: int, *, timeout: float = 0.1, device_dir: str = "/dev",
                 opener: Optional[Callable[[str, int], int]] = None, ioctl: Optional[Ioctl] = None,
                 closer: Optional[Callable[[int], None]] = None) -> None:
        if isinstance(bus, bool) or not isinstance(bus, int) or bus < 0:
            raise RegisterRangeError(f"I2C bus number must be an int >= 0, got {bus!r}")
        if not 0 < timeout <= 10:
            raise RegisterRangeError(f"I2C timeout must be in (0, 10] seconds, got {timeout!r}")
        self.bus = bus
        self.path = os.path.join(device_dir, f"i2c-{bus}")
        self.timeout = float(timeout)
        self._device_dir = device_dir
        self._open = opener if opener is not None else os.open
        self._ioctl = ioctl if ioctl is not None else _fcntl_ioctl
        self._close = closer if closer is not None else os.close
        self._fd: Optional[int] = None
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"LinuxI2CBus({self.path})"

    # -- lifecycle ------------------------------------------------------------------------

    def open(self) -> None:
        """Open the device and set the adapter timeout; raises :class:`I2CError` saying what is wrong."""
        with self._lock:
            self._ensure_open()

    def close(self) -> None:
        with self._lock:
            fd, self._fd = self._fd, None
            if fd is not None:
                self._close(fd)

    def __enter__(self) -> "LinuxI2CBus":
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _ensure_open(self) -> int:
        if self._fd is not None:
            return self._fd
        try:
            fd = self._open(self.path, os.O_RDWR)
        except FileNotFoundError:
            present = sorted(glob.glob(os.path.join(self._device_dir, "i2c-*")))
            raise I2CError(
                f"{self.path} does not exist (buses present: {', '.join(present) or 'none'}): "
                "check the board profile's i2c.bus, and that the i2c-dev module is loaded",
                bus=self.path) from None
        except PermissionError:  # EPERM (a cgroup's device list) or EACCES (the node's mode)
            raise I2CDenied(f"permission denied opening {self.path}: run the daemon as root or in the "
                            "group that owns the device (usually 'i2c')", bus=self.path) from None
        except OSError as exc:
            raise I2CError(f"cannot open {self.path}: {exc.strerror or exc}", bus=self.path) from None
        try:
            self._ioctl(fd, I2C_TIMEOUT, max(1, math.ceil(round(self.timeout * 100, 6))))
        except OSError as exc:
            self._close(fd)
            raise I2CError(f"{self.path} refused the I2C_TIMEOUT ioctl ({exc.strerror or exc}): "
                           "is it an i2c-dev device?", bus=self.path) from None
        self._fd = fd
        return fd

    # -- transactions ---------------------------------------------------------------------

    def write16(self, address: int, register: int, value: int) -> None:
        """Write ``value`` to 16-bit register ``register`` of the device at ``address``."""
        check_transaction(address, register, value)
        data = (ctypes.c_uint8 * 3)(register, (value >> 8) & 0xFF, value & 0xFF)
        msgs = (_Msg * 1)(_Msg(address, 0, 3, ctypes.cast(data, ctypes.POINTER(ctypes.c_uint8))))
        self._transfer(msgs, address, register, f"writing {value:#06x} to")

    def read16(self, address: int, register: int) -> int:
        """The 16-bit value of register ``register`` of the device at ``address``."""
        check_transaction(address, register)
        reg = (ctypes.c_uint8 * 1)(register)
        data = (ctypes.c_uint8 * 2)()
        msgs = (_Msg * 2)(
            _Msg(address, 0, 1, ctypes.cast(reg, ctypes.POINTER(ctypes.c_uint8))),
            _Msg(address, I2C_M_RD, 2, ctypes.cast(data, ctypes.POINTER(ctypes.c_uint8))),
        )
        self._transfer(msgs, address, register, "reading")
        return (data[0] << 8) | data[1]

    def _transfer(self, msgs: "ctypes.Array[_Msg]", address: int, register: int, doing: str) -> None:
        request = _RdwrData(ctypes.cast(msgs, ctypes.POINTER(_Msg)), len(msgs))
        where = f"{doing} R0x{register:02X} of the device at I2C address {address:#04x} on {self.path}"
        with self._lock:
            fd = self._ensure_open()
            try:
                self._ioctl(fd, I2C_RDWR, request)
            except OSError as exc:
                raise _error_of(exc, where, doing, bus=self.path, address=address,
                                register=register) from None


def nack_error(bus: str, address: int, register: int, doing: str) -> I2CNack:
    """The :class:`I2CNack` of a device that did not answer (shared with the emulated bus)."""
    return I2CNack(
        f"no acknowledge {doing} R0x{register:02X} of the device at I2C address {address:#04x} on {bus}: "
        "is the sensor powered, its cable seated and its address strap what the board profile says?",
        bus=bus, address=address, register=register)


def _error_of(exc: OSError, where: str, doing: str, **ctx: Any) -> I2CError:
    code = exc.errno
    if code in (errno.ENXIO, errno.EREMOTEIO, errno.EIO):  # how adapters report a NACK
        return nack_error(ctx["bus"], ctx["address"], ctx["register"], doing)
    if code == errno.ETIMEDOUT:
        return I2CTimeout(f"timed out {where}: the bus may be stuck (SDA held low) or the adapter "
                          "unclocked", **ctx)
    if code == errno.EAGAIN:
        return I2CError(f"lost arbitration {where}: another master is driving the bus", **ctx)
    return I2CError(f"failed {where}: {exc.strerror or exc}", **ctx)


def _fcntl_ioctl(fd: int, request: int, arg: Any) -> Any:
    import fcntl  # POSIX only: imported where it is needed, never at import time

    return fcntl.ioctl(fd, request, arg)
