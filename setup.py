"""stereocam: the Zynq stereo camera daemon, its FPGA rectify core model and emulated fabric.

The repository follows the design card in SYSTEM.md: ``board/``, ``overlays/``,
``drivers/`` and ``server/`` live at the top of the tree and are installed as
sub-packages of ``stereocam`` (``stereocam.overlays`` and so on).
"""
from setuptools import setup

SUBPACKAGES = {
    "stereocam": "stereocam",
    "stereocam.board": "board",
    "stereocam.overlays": "overlays",
    "stereocam.overlays.spec": "overlays/spec",
    "stereocam.overlays.model": "overlays/model",
    "stereocam.overlays.emulated": "overlays/emulated",
    "stereocam.drivers": "drivers",
    "stereocam.server": "server",
}

setup(
    name="stereocam",
    version="0.1.0",
    description="Zynq stereo camera daemon: FPGA rectification, live view, captures, virtual camera",
    python_requires=">=3.10",
    packages=list(SUBPACKAGES),
    package_dir=SUBPACKAGES,
    package_data={
        # rtl/: the rectify core's Verilog, for simulation and synthesis (stereocam.hdl.rtl_dir());
        # rtl/sim/: the C++ harness that makes it a program (stereocam.rtl_core).
        # rtl/camera/: the camera input IP; vivado/: the overlay's build scripts; *.bit, *.hwh: a built
        # overlay installed where --backend pynq looks first.
        "stereocam.overlays": ["*.md", "rtl/*.v", "rtl/*.vh", "rtl/*.sv", "rtl/*.md", "rtl/sim/*.cpp",
                               "rtl/camera/*.v", "rtl/camera/*.vh", "rtl/camera/*.md",
                               "vivado/*.tcl", "vivado/*.xdc", "vivado/*.sh", "vivado/*.md", "*.bit", "*.hwh"],
        "stereocam.board": ["*.service", "*.yaml"],
        "stereocam.server": ["static/*"],
    },
    install_requires=[
        "numpy>=1.21",
        # The PYNQ image (armv7l) ships OpenCV outside pip; building the wheel there takes hours.
        "opencv-python-headless>=4.5.4; platform_machine != 'armv7l'",
        "aiohttp>=3.9",  # web.AppKey
        "pillow>=9.0",
        "pyyaml>=5.4",
        # MATLAB .mat calibration import (scipy.io.loadmat). The PYNQ image ships scipy outside pip.
        "scipy>=1.7; platform_machine != 'armv7l'",
    ],
    extras_require={"board": ["pynq>=3.0"]},
    entry_points={
        "console_scripts": ["stereocam=stereocam.cli:main"],
        # pynq imports these in every process that makes an Overlay, before it downloads: the guard
        # refuses a download while the daemon owns the fabric (overlays/pynq_guard.py).
        "pynq.lib": ["stereocam-guard=stereocam.overlays.pynq_guard"],
    },
)
