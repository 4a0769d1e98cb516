"""Kitsu through ``gazu``: the approved take's MP4 as a preview on the shot's animation task,
the note as the comment, with a status.

Settings (a dict, else the environment): ``url`` (``TWEEN_KITSU_URL``, the API root, e.g.
``https://kitsu.studio/api``), ``user``/``password`` (``TWEEN_KITSU_USER``,
``TWEEN_KITSU_PASSWORD``), ``project`` (``TWEEN_KITSU_PROJECT``), ``task_type``
(``TWEEN_KITSU_TASK_TYPE``, default Animation), ``status`` (``TWEEN_KITSU_STATUS``, a status's
short name, default ``wfa``).
"""

from __future__ import annotations

import os
import time

from dailies.tracker import ApprovedTake, TrackerError

ENV = {"url": "TWEEN_KITSU_URL", "user": "TWEEN_KITSU_USER", "password": "TWEEN_KITSU_PASSWORD",
       "project": "TWEEN_KITSU_PROJECT", "task_type": "TWEEN_KITSU_TASK_TYPE", "status": "TWEEN_KITSU_STATUS"}  # fmt: skip
DEFAULTS = {"task_type": "Animation", "status": "wfa"}
#: How long the server may take to process an uploaded movie before it is called stuck.
PROCESSING_S = 120.0


class Kitsu:
    name = "kitsu"

    def __init__(self, url: str, user: str, password: str, project: str, task_type: str, status: str):
        self.url, self.user, self.password = url.rstrip("/"), user, password
        self.project, self.task_type, self.status = project, task_type, status

    @classmethod
    def from_settings(cls, settings: dict | None = None) -> Kitsu:
        s = {
            **DEFAULTS,
            **{k: os.environ[v] for k, v in ENV.items() if os.environ.get(v)},
            **(settings or {}),
        }
        missing = [ENV[k] for k in ("url", "user", "password", "project") if not s.get(k)]
        if missing:
            raise TrackerError(f"kitsu: not configured: set {', '.join(missing)}")
        try:
            import gazu  # noqa: F401
        except ImportError:
            raise TrackerError("kitsu: the gazu client is not installed (pip install gazu)") from None
        return cls(*(str(s[k]) for k in ("url", "user", "password", "project", "task_type", "status")))

    def _client(self):
        import gazu
        from gazu.exception import AuthFailedException

        client = gazu.client.create_client(self.url)
        try:
            gazu.log_in(self.user, self.password, client=client)
        except AuthFailedException:
            raise TrackerError(f"kitsu {self.url}: login refused for {self.user}") from None
        except Exception as e:  # unreachable host, not a Kitsu: said in one line
            raise TrackerError(f"kitsu {self.url}: cannot connect: {type(e).__name__}: {e}") from None
        return client

    def find_task(self, client, sequence: str, shot: str) -> dict:
        """The shot's task of this type, found by names; a missing one is one line naming it."""
        import gazu

        where = f"kitsu {self.url}"
        project = gazu.project.get_project_by_name(self.project, client=client)
        if not project:
            raise TrackerError(f"{where}: no project {self.project!r}")
        seq = gazu.shot.get_sequence_by_name(project, sequence, client=client)
        if not seq:
            raise TrackerError(f"{where}: project {self.project!r} has no sequence {sequence!r}")
        sh = gazu.shot.get_shot_by_name(seq, shot, client=client)
        if not sh:
            raise TrackerError(f"{where}: sequence {sequence!r} of {self.project!r} has no shot {shot!r}")
        tt = gazu.task.get_task_type_by_name(self.task_type, client=client)
        task = gazu.task.get_task_by_entity(sh, tt, client=client) if tt else None
        if not task:
            raise TrackerError(f"{where}: shot {sequence}/{shot} has no {self.task_type!r} task")
        return task

    def send(self, take: ApprovedTake) -> dict:
        import gazu

        client = self._client()
        task = self.find_task(client, take.sequence, take.shot)
        status = gazu.task.get_task_status_by_short_name(self.status, client=client)
        if not status:
            raise TrackerError(f"kitsu {self.url}: no task status {self.status!r}")
        text = take.note or f"take {take.take} approved"
        comment = (
            f"{text}\n\n(usd-tween: take {take.take} of {take.layer}, approved by {take.by} at {take.at})"
        )
        # Our MP4s have no audio track; zou's normalisation re-muxes such a movie with
        # B-frames into one without video (a "broken" preview). The file is stored as made:
        # H.264 Main 4:2:0 with faststart, which browsers play as it is.
        comment, preview = gazu.task.publish_preview(
            task,
            status,
            comment=comment,
            preview_file_path=str(take.mp4),
            normalize_movie=False,
            client=client,
        )
        state = self._processed(client, preview)
        return {"task": task["id"], "comment": comment["id"], "preview": preview["id"], "status": self.status,
                "preview_status": state}  # fmt: skip

    def _processed(self, client, preview: dict) -> str:
        """Waits for the server to process the upload; a broken preview is an error, never
        a silent success."""
        import gazu

        t0 = time.monotonic()
        while True:
            state = gazu.files.get_preview_file(preview["id"], client=client).get("status") or "ready"
            if state == "broken":
                raise TrackerError(
                    f"kitsu {self.url}: the server could not process the preview {preview['id']}"
                )
            if state != "processing":
                return state
            if time.monotonic() - t0 > PROCESSING_S:
                raise TrackerError(
                    f"kitsu {self.url}: preview {preview['id']} still processing after {PROCESSING_S:g} s"
                )
            time.sleep(0.5)
