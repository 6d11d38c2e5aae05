"""Run a capture plan position by position: move, wait Idle, light on, trigger, light off, commit
the image, append its manifest line. Resumable and loss-free (see folder.py): a restart skips the
positions already recorded and never shoots one twice; Ctrl-C, exceptions and a vanished port
leave the folder consistent, and the light is switched off on the way out when the port works.

A mesh_views plan's images (rig.plan.targets_from_views_plan) trigger the camera each names, with the light at
its world position; their manifest lines add camera, light and light_mm (the world position reached), and the
folder's images.json and lights.json are rewritten from the manifest after each image (rig.views_index).
"""

from __future__ import annotations

import time
from datetime import datetime, timezone

import numpy as np

from torchrefl.errors import RigError
from torchrefl.rig.board_check import check_connected_board
from torchrefl.rig.camera import Camera
from torchrefl.rig.folder import CaptureFolder
from torchrefl.rig.grbl import ControllerReset, GrblAlarm, GrblClient
from torchrefl.rig.link import PortLost
from torchrefl.rig.model import RigModel
from torchrefl.rig.plan import Target, order_points, path_length, target_key, unique_targets
from torchrefl.rig.settings import RigSettings
from torchrefl.rig.views_index import write_views_index


def _utc_now() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


class CaptureRunner:
    """Executes targets with a GrblClient (its link may be closed: run() opens it), a RigModel,
    a Camera and a CaptureFolder. progress: callable(str), one line per position."""

    MAX_RECOVERIES = 5

    def __init__(
        self,
        client: GrblClient,
        model: RigModel,
        camera: Camera,
        folder: CaptureFolder,
        settings: RigSettings,
        progress=print,
    ):
        self.client, self.model, self.camera, self.folder = client, model, camera, folder
        self.s = settings
        self.progress = progress or (lambda msg: None)
        self.summary: dict = {}

    # ---------------------------------------------------------------- controller

    def _start(self) -> None:
        if not self.client.link.is_open:
            self.client.link.open()
        self.client.connect()
        check_connected_board(self.client, self.s, self.progress)
        st = self.client.last_status
        if self.s.home_on_start or st.state == "Alarm":
            if st.state == "Alarm" and not self.s.home_on_start:
                raise GrblAlarm(
                    f"{self.client.port}: the controller is locked in the Alarm state ({st.raw}); home it "
                    f"(home_on_start: true, or `python -m torchrefl.rig home`) before capturing",
                    None,
                )
            self.client.home(progress=self.progress)

    def _light_off_quietly(self) -> str:
        """Switch the light off if the controller can hear us; returns a note for the report."""
        c = self.client
        if not c.link.is_open:
            return "light not switched off: the port is gone (GRBL switches its outputs off when it resets)"
        if c.rebooted:
            return (
                "light not switched off by the rig: the controller rebooted, which switched its outputs off, "
                "and it stays locked (it would refuse M9) until homed"
            )
        if c.alarm is not None:
            return "light not switched off by the rig: GRBL switched spindle and coolant off with the alarm"
        try:
            c.command(self.model.light_off_command())
            return "light off"
        except RigError as exc:
            return f"light off failed: {exc}"

    # ---------------------------------------------------------------- one position

    def _shoot(self, t: Target, index: int) -> dict:
        c, m = self.client, self.model
        axes = m.target(t.requested_mm, what=f"position {t.requested_mm.tolist()}")
        c.move_to(axes, self.s.feed_mm_min)
        st = c.wait_idle()
        reached = m.axes_to_head(st.mpos)
        err = float(np.linalg.norm(reached - t.requested_mm))
        if err > self.s.position_tolerance_mm:
            raise RigError(
                f"{c.port}: requested light position {t.requested_mm.tolist()} but the controller reports "
                f"{reached.tolist()} ({err:.3f} mm away, tolerance position_tolerance_mm = "
                f"{self.s.position_tolerance_mm}); status {st.raw}"
            )
        temp = self.folder.temp_path(index)
        self.folder.discard(temp)
        c.command(m.light_on_command())
        try:
            if self.s.light.settle_s > 0:
                time.sleep(self.s.light.settle_s)
            if t.camera is None:
                self.camera.capture(temp, reached)
            else:
                self.camera.capture(temp, t.world_mm(reached), camera=t.camera)
        except BaseException:
            self.folder.discard(temp)
            self._light_off_quietly()
            raise
        c.command(m.light_off_command())
        entry = {
            "index": index,
            "image": self.folder.image_name(index),
            "position_mm": [float(v) for v in reached],
            "requested_mm": [float(v) for v in t.requested_mm],
            "mpos": [float(v) for v in st.mpos],
            "grid": list(t.grid) if t.grid is not None else None,
            "time": _utc_now(),
        }
        if t.camera is not None:
            entry.update(camera=t.camera, light=t.light, light_mm=[float(v) for v in t.world_mm(reached)])
        self.folder.commit(temp, entry)
        if t.camera is not None:
            write_views_index(self.folder.root, self.folder.entries, self.s.light.intensity, self.s.camera.encoding)
        return entry

    def _views_note(self, targets: list[Target]) -> None:
        """Check the camera trigger against a mesh_views plan's cameras and say what the folder still needs."""
        self.camera.check_cameras([t.camera for t in targets])
        missing = [n for n in ("cameras.json", "mesh.obj | mesh.ply | mesh.glb") if not self._has(n)]
        if missing:
            self.progress(
                f"note: {self.folder.root} has no {' and no '.join(missing)}; add the cameras and the mesh the plan "
                "was made with before fitting (images.json and lights.json are written from the manifest)"
            )

    def _has(self, names: str) -> bool:
        return any((self.folder.root / n.strip()).is_file() for n in names.split("|"))

    # ---------------------------------------------------------------- recovery

    def _recover(self, exc: RigError) -> bool:
        """After a vanished port or an unrequested reset: reconnect / re-home when the settings
        allow it (returns True to go on), else False."""
        c = self.client
        if isinstance(exc, PortLost) and self.s.timeouts.reconnect_s > 0:
            self.progress(f"port lost ({exc}); reopening {c.port} within {self.s.timeouts.reconnect_s:.1f} s")
            c.link.reopen(self.s.timeouts.reconnect_s)
            c.connect()
            check_connected_board(c, self.s, self.progress)
            self.progress("reconnected; the controller restarted, so the rig is homed again ($H)")
            c.home(progress=self.progress)
            self.summary["reconnects"] += 1
            return True
        if isinstance(exc, ControllerReset) and self.s.rehome_on_reset:
            self.progress(f"{exc}; homing again ($H) as rehome_on_reset is set, then the capture goes on")
            c._settle(0.1)
            check_connected_board(c, self.s, self.progress)
            c.home(progress=self.progress)
            self.summary["rehomes"] += 1
            return True
        return False

    # ---------------------------------------------------------------- the plan

    def run(self, targets: list[Target]) -> dict:
        """Capture every target not yet in the manifest. Returns a summary dict: captured,
        skipped (already recorded), total, path_mm, reconnects, rehomes, recovered (folder repairs)."""
        targets = unique_targets(list(targets))
        self.summary = {"total": len(targets), "captured": 0, "skipped": 0, "reconnects": 0, "rehomes": 0}
        self.summary["recovered"] = self.folder.recover()
        views = any(t.camera is not None for t in targets)
        if views:
            self._views_note(targets)
            write_views_index(self.folder.root, self.folder.entries, self.s.light.intensity, self.s.camera.encoding)
        elif self.folder.link_scan_yaml() is False:
            self.progress(
                f"note: {self.folder.root}/scan.yaml not found; the scanner's scan.yaml and range.npy "
                f"must be added (with lights: manifest.jsonl) before fitting"
            )
        done = {
            target_key(e["requested_mm"], e.get("camera"))
            for e in self.folder.entries
            if e.get("requested_mm") is not None
        }
        remaining = [t for t in targets if t.key not in done]
        self.summary["skipped"] = len(targets) - len(remaining)
        for t in remaining:  # soft limits for the whole plan, before anything is sent
            self.model.target(t.requested_mm, what=f"plan position {t.requested_mm.tolist()}")
        if not remaining:
            self.progress(f"nothing to do: all {len(targets)} positions are recorded in {self.folder.manifest}")
            self.summary["path_mm"] = 0.0
            return self.summary
        notes = []
        try:
            self._start()
            here = self.model.axes_to_head(self.client.last_status.mpos)[:2]
            pts = np.array([t.requested_mm[:2] for t in remaining])
            order = order_points(pts, start=here)
            self.summary["path_mm"] = path_length(pts, order, start=here)
            queue = [remaining[k] for k in order]
            recoveries = 0
            while queue:
                t = queue[0]
                index = self.folder.next_index()
                try:
                    entry = self._shoot(t, index)
                except (PortLost, ControllerReset) as exc:
                    recoveries += 1
                    if recoveries > self.MAX_RECOVERIES or not self._recover(exc):
                        raise
                    continue
                queue.pop(0)
                self.summary["captured"] += 1
                n = self.summary["skipped"] + self.summary["captured"]
                grid = f" grid {tuple(t.grid)}" if t.grid is not None else ""
                grid += f" camera {t.camera} light {t.light}" if t.camera is not None else ""
                self.progress(
                    f"[{n}/{len(targets)}] {entry['image']}{grid} requested "
                    f"{np.round(t.requested_mm, 3).tolist()} reached {np.round(entry['position_mm'], 3).tolist()} "
                    f"(MPos {np.round(entry['mpos'], 3).tolist()})"
                )
        except BaseException as exc:
            notes.append(self._light_off_quietly())
            left = len(remaining) - self.summary["captured"]
            then = "it homes ($H) first, then shoots" if self.s.home_on_start else "it shoots"
            self.progress(
                f"capture stopped after {self.summary['captured']} new images; the folder is consistent "
                f"({len(self.folder.entries)} recorded); {notes[-1]}; run the same command again to resume: "
                f"{then} the {left} positions not yet recorded"
                + (
                    " (the controller rebooted: its position is lost until homed)"
                    if isinstance(exc, ControllerReset)
                    else ""
                )
            )
            raise
        finally:
            self.summary["status_retries"] = self.client.status_retried
        return self.summary
