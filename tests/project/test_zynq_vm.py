"""The Zynq VM (``scripts/zynq-vm``, the ``zynq`` env of ``./scripts/test``) checks the service the daemon
installs: these tests keep its pieces in step with the unit, so a driver or device the unit gains is one
the VM's kernel has and its checks open. The VM itself runs in CI as its own env."""
from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from types import ModuleType
from typing import Dict

from stereocam.server.http import systemd

ROOT = Path(__file__).resolve().parents[2]
ZYNQ = ROOT / "scripts" / "zynq"
# The kernel option of each driver module the unit loads through modprobe@ (systemd.DRIVER_MODULES).
MODULE_OPTIONS = {"i2c-dev": "CONFIG_I2C_CHARDEV", "uio_pdrv_genirq": "CONFIG_UIO_PDRV_GENIRQ"}
# The kernel options behind each DeviceAllow= entry of the unit (systemd.DEVICES).
DEVICE_OPTIONS = {"/dev/mem": "CONFIG_DEVMEM", "char-uio": "CONFIG_UIO", "char-i2c": "CONFIG_I2C",
                  "char-drm": "CONFIG_DRM"}


def load_check() -> ModuleType:
    spec = importlib.util.spec_from_file_location("zynq_check", ZYNQ / "check.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def kernel_options() -> Dict[str, str]:
    options = {}
    for line in (ZYNQ / "kernel.config").read_text().splitlines():
        m = re.fullmatch(r"(CONFIG_[A-Za-z0-9_]+)=(\S+)", line.strip())
        if m:
            options[m.group(1)] = m.group(2)
    return options


def test_the_checks_look_for_the_service_where_install_service_puts_it() -> None:
    check = load_check()
    assert check.UNIT == systemd.UNIT_NAME
    assert check.VENV == systemd.PYNQ_VENV
    assert check.PORT == systemd.DEFAULT_PORT


def test_the_kernel_builds_every_driver_the_unit_loads_as_a_module() -> None:
    options = kernel_options()
    assert {module for module, _ in systemd.DRIVER_MODULES} == set(MODULE_OPTIONS)
    for module, option in MODULE_OPTIONS.items():
        assert options.get(option) == "m", f"{module}: {option} must be a module, for the late-driver check"


def test_the_kernel_has_every_device_the_unit_allows() -> None:
    options = kernel_options()
    assert {name for name, _ in systemd.DEVICES} == set(DEVICE_OPTIONS)
    for name, option in DEVICE_OPTIONS.items():
        assert options.get(option) in ("y", "m"), f"{name}: the VM's kernel lacks {option}"
    # systemd enforces DeviceAllow= with a cgroup BPF program; without it the device checks prove nothing.
    assert options.get("CONFIG_CGROUP_BPF") == "y" and options.get("CONFIG_BPF_SYSCALL") == "y"


def test_the_device_tree_gives_the_fabric_interrupt_to_uio_as_pynq_does() -> None:
    dts = (ZYNQ / "stereocam-vm.dts").read_text()
    assert 'compatible = "generic-uio"' in dts
    assert "of_id=generic-uio" in (ROOT / "scripts" / "_zynq.sh").read_text()
