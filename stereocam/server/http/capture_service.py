"""The app's :class:`~..frames.capturing.CaptureService`, made from the app's state when a route needs it.

Made at each use (a few references): the stages it is handed are the ones the app holds
then, and the frame wait is read from the settings at each grab.
"""
from __future__ import annotations

from aiohttp import web

from ..frames.capturing import CaptureService
from .state import CALIBRATION, EXECUTORS, EXTENSIONS, FEED, OVERLAY, PIPELINE, SETTINGS, VIRTUAL

__all__ = ["capture_service"]


def capture_service(app: web.Application) -> CaptureService:
    """What ``POST /api/captures`` and the calibration panel's pairs capture with."""
    return CaptureService(
        feed=app[FEED], pipeline=app[PIPELINE], overlay=app[OVERLAY], virtual=app[VIRTUAL],
        calibration=app[CALIBRATION], run=app[EXECUTORS].run,
        frame_wait_s=lambda: app[SETTINGS].frame_wait_s, sections=app[EXTENSIONS].capture_sections)
