"""The camera sensors over HTTP: ``GET/PUT /api/cameras``; status, metrics, faults, capture data.

At startup (before the fabric's streams start) the extension brings up the
board's two MT9V034s through :class:`stereocam.overlays.interface.StereoSensors` (the MT9V034 driver)
on the bus :func:`stereocam.overlays.backend.sensor_bus` gives for the
overlay: on the emulated backend an emulated pair attached to the fabric (it
drives the camera source's exposure, gain, flips and test patterns), on the
pynq backend ``/dev/i2c-<n>`` of the board profile. Bring-up never stops the
daemon: a sensor that does not answer or is not an MT9V034 is logged and
reported (``/api/status`` ``sensors``, ``/metrics`` ``stereocam_sensor_ok``,
and a fault ``sensor.left``/``sensor.right`` in ``app[EXTENSIONS].faults``)
and the streams keep running.

Every :data:`REFRESH_S` seconds a check (:meth:`StereoSensors.check`)
notices a sensor that stopped answering and sets one that answers again up
as at start, with the controls the user last applied; the values in use are
read every :data:`VALUES_EVERY` checks, and at once when a sensor comes or
goes. Every I2C call runs on the daemon's ``work`` threads. The providers
(status, metrics, faults, capture metadata) read a snapshot refreshed after
every call, so they never block the loop.
"""
from __future__ import annotations

import asyncio
import logging
import threading
from dataclasses import dataclass, field
from typing import Any, AsyncIterator, Callable, Dict, List, Optional

from aiohttp import web
from prometheus_client.core import GaugeMetricFamily, Metric

from ...board.profile import BoardProfile, load_profile
from ...overlays.backend import sensor_bus
from ...overlays.interface import (
    CAMERAS,
    I2CBus,
    I2CDenied,
    I2CError,
    Overlay,
    SensorPair,
    SensorUnavailable,
    StereoSensors,
)
from ..errors import ApiError
from .bodies import json_response, read_json
from .state import EXECUTORS, EXTENSIONS, OVERLAY, SETTINGS
from .systemd import LateDriver, under_systemd

log = logging.getLogger(__name__)

__all__ = ["setup", "extension", "CameraService", "CAMERA_SERVICE", "REFRESH_S", "VALUES_EVERY"]

# A sensor that stops answering must show within 1 s and one that answers again be back within
# 2 s of it. A check is two register reads (~0.2 ms of bus on the board), so checking
# four times a second bounds both at about a quarter of a second plus one work-thread hop; the
# values in use (14 reads, the AEC's exposure moving) are read once a second.
REFRESH_S = 0.25
VALUES_EVERY = 4
TARGETS = ("both", "left", "right")


@dataclass
class CameraService:
    """The sensors the daemon controls (None when they could not be set up: ``error`` says why)."""

    sensors: Optional[StereoSensors] = None
    pair: Optional[SensorPair] = None  # the emulated backend's sensors (the overlay's ``sensors``)
    bus: Optional[I2CBus] = None
    error: Optional[str] = "not started"
    health: Dict[str, Any] = field(default_factory=dict)
    values: Dict[str, Optional[Dict[str, Any]]] = field(default_factory=dict)
    active: List[Dict[str, Any]] = field(default_factory=list)  # the faults of the last refresh
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _refreshing: threading.Lock = field(default_factory=threading.Lock)
    _ticks: int = 0

    # -- blocking (work threads) -----------------------------------------------------------

    def refresh(self, *, values: bool = True) -> Dict[str, Any]:
        """Check the sensors and read the values in use (blocks for I2C); returns the GET body.

        The check re-probes a sensor that is unavailable (see
        :meth:`StereoSensors.check`). With ``values`` False the values are
        read only if a sensor came or went. Refreshes are serialised, so an
        older one never overwrites a newer snapshot.
        """
        if self.sensors is None:
            return self.snapshot()
        with self._refreshing:
            health = self.sensors.check()
            with self._lock:
                was_up = {c for c in CAMERAS if (self.health.get(c) or {}).get("ok")}
                read = dict(self.values)
            if values or was_up != {c for c in CAMERAS if health[c]["ok"]}:
                read = self.sensors.read()
                health = self.sensors.health()  # a read may have marked one
            faults = self.sensors.faults()
            with self._lock:
                self.values, self.health, self.active = read, health, faults
        return self.snapshot()

    def tick(self) -> None:
        """One periodic refresh: the check every time, the values every :data:`VALUES_EVERY` ticks."""
        self._ticks += 1
        self.refresh(values=self._ticks % VALUES_EVERY == 0)

    def apply(self, body: Dict[str, Any], camera: str) -> Dict[str, Any]:
        assert self.sensors is not None
        try:
            self.sensors.apply(body, camera=camera)
        finally:
            self.refresh()
        return self.snapshot()

    # -- snapshot (any thread, never blocks on I2C) -------------------------------------------

    def snapshot(self) -> Dict[str, Any]:
        with self._lock:
            out: Dict[str, Any] = {c: self.values.get(c) for c in CAMERAS}
            health: Dict[str, Any] = dict(self.health) if self.health else {"ok": False}
        if self.error is not None and self.sensors is None:
            health["error"] = self.error
        out["health"] = health
        return out

    def status(self) -> Dict[str, Any]:
        snap = self.snapshot()
        return {"ok": bool(snap["health"].get("ok")), "health": snap["health"],
                "values": {c: snap[c] for c in CAMERAS}}

    def faults(self) -> List[Dict[str, Any]]:
        """The sensors unavailable now (a :data:`.state.FaultProvider`), from the snapshot."""
        with self._lock:
            return [dict(f) for f in self.active]

    def capture_meta(self) -> Dict[str, Any]:
        snap = self.snapshot()
        return {c: snap[c] for c in CAMERAS}

    def metrics(self) -> List[Metric]:
        """The sensors' gauges (``Extensions.metrics`` provider; from the snapshot, never I2C).

        ``stereocam_sensor_ok{camera}`` always; ``stereocam_sensor_exposure_seconds``,
        ``stereocam_sensor_gain``, ``stereocam_sensor_auto_exposure_enabled`` and
        ``stereocam_sensor_auto_gain_enabled`` (each ``{camera}``) for the sensors whose
        values are known.
        """
        snap = self.snapshot()
        health = snap["health"]
        ok = GaugeMetricFamily("stereocam_sensor_ok", "1 if the camera sensor answers and is set up.",
                               labels=["camera"])
        for c in CAMERAS:
            ok.add_metric([c], 1.0 if (health.get(c) or {}).get("ok") else 0.0)
        out: List[Metric] = [ok]
        gauges = (  # snapshot key, its units in the base unit, family, help
            ("exposure_us", 1e6, "stereocam_sensor_exposure_seconds", "The sensor's exposure time in use."),
            ("gain", 1.0, "stereocam_sensor_gain", "The sensor's analog gain in use (a factor)."),
            ("aec", 1.0, "stereocam_sensor_auto_exposure_enabled", "1 if the sensor's auto exposure is on."),
            ("agc", 1.0, "stereocam_sensor_auto_gain_enabled", "1 if the sensor's auto gain is on."))
        for key, per, name, text in gauges:
            rows = [(c, snap[c][key]) for c in CAMERAS
                    if snap[c] is not None and snap[c].get(key) is not None]
            if not rows:
                continue
            family = GaugeMetricFamily(name, text, labels=["camera"])
            for c, value in rows:
                family.add_metric([c], float(value) / per)
            out.append(family)
        return out


CAMERA_SERVICE: "web.AppKey[CameraService]" = web.AppKey("stereocam.cameras", CameraService)


# -- bring-up ------------------------------------------------------------------------------------

def _open_sensors(service: CameraService, overlay: Overlay, profile: Optional[BoardProfile],
                  pair_options: Dict[str, Any], board: Optional[str] = None) -> None:
    """Bring up the overlay's sensor bus (:func:`~stereocam.overlays.backend.sensor_bus`) and the
    sensors on it (blocks; never raises).

    ``profile`` None: the file ``board`` names (the config's ``board``, which ``stereocam serve``
    resolved and checked at start), else the packaged default.
    """
    try:
        if profile is None:
            profile = load_profile(board)
        log.info("board profile %s: %s", profile.name, profile.source)
        service.bus = sensor_bus(overlay, profile, **pair_options)
        _open_bus(service.bus)
        service.pair = overlay.sensors
        service.sensors = profile.stereo_sensors(service.bus)
        service.error = None
        health = service.sensors.start()
        service.refresh()
        if not health.get("ok"):
            log.error("camera sensors: not all are up (%s); the daemon keeps serving",
                      "; ".join(f"{c}: {health[c]['error']}" for c in CAMERAS if health[c].get("error")))
    except LateDriver:
        raise
    except Exception as exc:  # the daemon serves without sensor control rather than not at all
        log.error("camera sensors cannot be controlled: %s", exc)
        service.sensors = None
        service.error = str(exc)


def _open_bus(bus: I2CBus) -> None:
    """Open the board's bus now (a bus with ``open``; blocks). Under systemd a node that exists but is
    refused raises :class:`~.systemd.LateDriver`: the unit's device list (``DeviceAllow=char-i2c``) was
    made before i2c-dev loaded, and only a restart reads it again (``stereocam serve`` exits with
    :data:`~.systemd.LATE_DRIVER_EXIT`, which the unit restarts on). Any other failure is left to the
    sensors' start, which reports it per camera and serves on.
    """
    opener = getattr(bus, "open", None)
    if not callable(opener):
        return
    try:
        opener()
    except I2CDenied as exc:
        if under_systemd():
            raise LateDriver(exc.bus or repr(bus), "permission denied") from None
    except I2CError:
        pass


async def _refresh_loop(app: web.Application, service: CameraService) -> None:
    """:meth:`CameraService.tick` every :data:`REFRESH_S` s on a work thread (never two at once)."""
    failing: Optional[str] = None
    while True:
        await asyncio.sleep(REFRESH_S)
        try:
            await app[EXECUTORS].run(service.tick)
            failing = None
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # pragma: no cover - check() and read() do not raise for a sensor
            if str(exc) != failing:  # once, not four times a second
                log.warning("camera sensors: refresh failed: %s", exc)
            failing = str(exc)


def _sensors_ctx(profile: Optional[BoardProfile], pair_options: Dict[str, Any]
                 ) -> Callable[[web.Application], AsyncIterator[None]]:
    async def ctx(app: web.Application) -> AsyncIterator[None]:
        service = app[CAMERA_SERVICE]
        loop = asyncio.get_running_loop()
        board = app[SETTINGS].board
        await app[EXECUTORS].run(_open_sensors, service, app[OVERLAY], profile, pair_options, board)
        task = loop.create_task(_refresh_loop(app, service), name="stereocam-sensors")
        try:
            yield
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            close = getattr(service.bus, "close", None)
            if service.pair is None and callable(close):
                try:
                    close()
                except Exception as exc:  # pragma: no cover
                    log.warning("closing the I2C bus: %s", exc)

    return ctx


# -- routes ----------------------------------------------------------------------------------------

def _unavailable(service: CameraService) -> ApiError:
    return ApiError(f"the camera sensors cannot be controlled: {service.error}", status=503)


async def get_cameras(request: web.Request) -> web.Response:
    service = request.app[CAMERA_SERVICE]
    body = await request.app[EXECUTORS].run(service.refresh)
    return json_response(body)


async def put_cameras(request: web.Request) -> web.Response:
    service = request.app[CAMERA_SERVICE]
    body = await read_json(request, example='{"exposure_us": 5000, "gain": 2.0, "camera": "both"}')
    if not isinstance(body, dict):
        raise ApiError("send a JSON object of camera settings, not " + type(body).__name__, status=400)
    camera = body.pop("camera", "both")
    if camera not in TARGETS:
        raise ApiError(f"camera {camera!r} is not one of: both, left, right", status=400)
    if service.sensors is None:
        raise _unavailable(service)
    try:
        answer = await request.app[EXECUTORS].run(service.apply, body, camera)
    except SensorUnavailable as exc:
        raise ApiError(str(exc), status=503) from None
    except ValueError as exc:
        raise ApiError(str(exc), status=400) from None
    return json_response(answer)


def extension(*, profile: Optional[BoardProfile] = None,
              **pair_options: Any) -> Callable[[web.Application], None]:
    """A ``setup`` with another board profile (default: the config's ``board``, else the packaged one)
    or emulated-pair options."""

    def setup_(app: web.Application) -> None:
        service = CameraService()
        app[CAMERA_SERVICE] = service
        ext = app[EXTENSIONS]
        ext.status["sensors"] = service.status
        ext.metrics.append(service.metrics)
        ext.faults.append(service.faults)
        ext.capture_meta["cameras"] = service.capture_meta
        app.cleanup_ctx.append(_sensors_ctx(profile, pair_options))
        app.router.add_get("/api/cameras", get_cameras)
        app.router.add_put("/api/cameras", put_cameras)

    return setup_


def setup(app: web.Application) -> None:
    """The extension ``stereocam serve`` installs (see the module doc)."""
    extension()(app)
