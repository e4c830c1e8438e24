"""stereocam: software for the Zynq stereo camera board (see README.md)."""
__version__ = "0.1.0"
