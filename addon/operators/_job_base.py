"""Modal-timer plumbing shared by the simulate and reconstruct operators.

A subclass implements ``build_job(context) -> jobs.Job`` (raising UserError for a bad
state) and ``finish(context, job) -> set``. In the UI (invoke) the job runs in the
background: a timer polls it, the status bar shows progress, Esc cancels. From scripts
and in background mode (execute) it runs to completion, blocking.
"""

from __future__ import annotations

import time

import bpy

from .. import jobs
from ._common import UserError

TIMER_S = 0.25


def _set_status(context, text):
    ws = getattr(context, "workspace", None)
    if ws is not None:
        ws.status_text_set(text)


def _redraw_sidebars(context):
    wm = getattr(context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            if area.type in ("VIEW_3D", "PREFERENCES"):
                area.tag_redraw()


class JobOperatorMixin:
    job_kind = "job"
    _job = None
    _timer = None

    def build_job(self, context) -> jobs.Job:
        raise NotImplementedError

    def finish(self, context, job: jobs.Job) -> set:
        raise NotImplementedError

    def cleanup(self, context, job: jobs.Job | None):
        """Remove temporary files; runs after success, failure and cancel."""

    def _prepare(self, context):
        if jobs.active(self.job_kind) is not None:
            raise UserError(f"A {self.job_kind} job is already running: cancel it first (Esc or Cancel)")
        try:
            job = self.build_job(context)
        except UserError:
            self.cleanup(context, None)  # e.g. a temporary copy made before the failing check
            raise
        try:
            job.start()
        except OSError as exc:
            self.cleanup(context, job)
            raise UserError(f"Could not start {job.cmd[0]}: {exc.strerror or exc}") from None
        jobs.set_active(job, self.job_kind)
        return job

    def execute(self, context):
        try:
            job = self._prepare(context)
        except UserError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        last, last_t = None, 0.0
        try:
            while not job.poll():
                time.sleep(0.1)
                # echo progress on the console of a background run, at most every 2 s (tqdm redraws often)
                if job.last_line != last and time.monotonic() - last_t >= 2.0:
                    last, last_t = job.last_line, time.monotonic()
                    print(f"platolidar {self.job_kind}: {last}", flush=True)
        except KeyboardInterrupt:
            job.cancel()
        return self._complete(context, job)

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        try:
            self._job = self._prepare(context)
        except UserError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(TIMER_S, window=context.window)
        wm.modal_handler_add(self)
        _set_status(context, self._job.status_text())
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC" and event.value == "PRESS":
            job.cancel()
            return self._complete(context, job)
        if event.type == "TIMER":
            if job.cancelled or job.poll():
                return self._complete(context, job)
            _set_status(context, job.status_text())
            _redraw_sidebars(context)
        return {"PASS_THROUGH"}

    def _complete(self, context, job):
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        _set_status(context, None)
        jobs.set_active(None, self.job_kind)
        if not job.poll():
            job.cancel()
        try:
            if job.cancelled:
                self.report({"WARNING"}, f"{self.job_kind.capitalize()} cancelled after {job.elapsed:.0f} s")
                return {"CANCELLED"}
            if job.returncode != 0:
                self.report({"ERROR"}, f"{self.job_kind.capitalize()} failed (exit code {job.returncode}): "
                                       f"{job.failure_summary()}")
                return {"CANCELLED"}
            try:
                return self.finish(context, job)
            except UserError as exc:
                self.report({"ERROR"}, str(exc))
                return {"CANCELLED"}
        finally:
            self.cleanup(context, job)
            _redraw_sidebars(context)
