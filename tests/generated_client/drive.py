"""Drives a whole job through a client generated from openapi.yaml (openapi-python-client).

Run by tests/generated_client.rs against a real `pathfarm serve` with a real `pathfarm worker`:

    python drive.py BASE_URL SCENE OUT_DIR

with the generated package (`pathfarm_client`) importable. Every call goes through the generated
functions and models, never through raw HTTP, so what works here works for any user of the
generated client. Exits non-zero (an AssertionError with the reason) at the first answer that
is not what the contract promises; writes OUT_DIR/image.exr (the finished job's image, for the
Rust side to compare with a local render) and OUT_DIR/summary.json.
"""

import json
import sys
import time
from pathlib import Path

from pathfarm_client import Client
from pathfarm_client.api.images import get_job_image_exr, get_job_preview_png
from pathfarm_client.api.jobs import (
    cancel_job,
    delete_job,
    get_job,
    get_job_convergence,
    list_jobs,
    patch_job,
    pause_job,
    resume_job,
    submit_job,
)
from pathfarm_client.api.workers import list_workers
from pathfarm_client.models import (
    ErrorBody,
    JobCreated,
    JobPatch,
    JobSettings,
    JobState,
    JobView,
    SubmitJobBody,
)
from pathfarm_client.types import File


def expect(response, status, model=None, what=""):
    """The parsed answer, after checking its status (and its model)."""
    assert response.status_code == status, (
        f"{what}: HTTP {int(response.status_code)}, expected {status}: {response.content[:300]!r}"
    )
    if model is not None:
        assert isinstance(response.parsed, model), f"{what}: parsed {response.parsed!r}"
    return response.parsed


def job(client, job_id, what):
    return expect(get_job.sync_detailed(job_id, client=client), 200, JobView, what)


def wait_for(client, job_id, done, what, timeout=120.0):
    deadline = time.monotonic() + timeout
    while True:
        view = job(client, job_id, what)
        if done(view):
            return view
        assert time.monotonic() < deadline, f"{what}: timed out, job is {view.to_dict()}"
        time.sleep(0.05)


def submit(client, scene, name, **settings):
    body = SubmitJobBody(
        scene=File(payload=scene, file_name="cornell.gltf", mime_type="model/gltf+json"),
        settings=JobSettings(name=name, **settings),
    )
    created = expect(submit_job.sync_detailed(client=client, body=body), 201, JobCreated, "submit")
    return created.id


def main():
    base_url, scene_path, out_dir = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    scene = scene_path.read_bytes()
    summary = {}
    with Client(base_url=base_url, raise_on_unexpected_status=False) as client:
        # The job the worker renders to the end. Its optional settings are left absent, so the
        # server's defaults apply (the client sends nothing it was not given).
        job_id = submit(client, scene, "generated", width=48, height=48, spp=1024, tile_size=16)
        view = job(client, job_id, "the submitted job")
        assert view.settings.rr == "auto", view.settings.to_dict()
        assert view.settings.tile_size == 16, view.settings.to_dict()

        # Pause and resume while it renders, and change its priority.
        paused = expect(pause_job.sync_detailed(job_id, client=client), 200, JobView, "pause")
        assert paused.state == JobState.PAUSED, paused.state
        resumed = expect(resume_job.sync_detailed(job_id, client=client), 200, JobView, "resume")
        assert resumed.state in (JobState.QUEUED, JobState.RUNNING, JobState.COMPLETED), resumed.state
        patched = expect(
            patch_job.sync_detailed(job_id, client=client, body=JobPatch(priority=7)),
            200,
            JobView,
            "priority",
        )
        assert patched.priority == 7, patched.priority

        done = wait_for(client, job_id, lambda v: v.state == JobState.COMPLETED, "the job")
        assert done.samples_done == done.samples_planned == 48 * 48 * 1024, done.to_dict()
        assert done.priority == 7
        summary["samples_done"] = done.samples_done

        listed = expect(list_jobs.sync_detailed(client=client), 200, None, "list")
        assert job_id in [j.id for j in listed.jobs], [j.id for j in listed.jobs]

        history = expect(
            get_job_convergence.sync_detailed(job_id, client=client), 200, None, "convergence"
        )
        assert history.points, "no convergence point"
        assert history.points[-1].samples_done == done.samples_done, history.points[-1]
        summary["convergence_points"] = len(history.points)

        # Both downloads, each with its own validator: the tag of one is no match for the
        # other, and each answers 304 to itself.
        exr = get_job_image_exr.sync_detailed(job_id, client=client)
        expect(exr, 200, File, "image.exr")
        exr_tag = exr.headers["etag"]
        assert exr.content[:4] == b"\x76\x2f\x31\x01", "not an OpenEXR file"
        (out_dir / "image.exr").write_bytes(exr.parsed.payload.read())
        png = get_job_preview_png.sync_detailed(job_id, client=client, exposure=0.5)
        expect(png, 200, File, "preview.png")
        png_tag = png.headers["etag"]
        assert png.content[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG file"
        assert exr_tag != png_tag, (exr_tag, png_tag)
        again = get_job_image_exr.sync_detailed(job_id, client=client, if_none_match=exr_tag)
        expect(again, 304, None, "image.exr revalidated")
        assert again.content == b"" and again.headers["etag"] == exr_tag
        other = get_job_image_exr.sync_detailed(job_id, client=client, if_none_match=png_tag)
        expect(other, 200, File, "image.exr with the PNG's tag")
        again = get_job_preview_png.sync_detailed(
            job_id, client=client, exposure=0.5, if_none_match=png_tag
        )
        expect(again, 304, None, "preview.png revalidated")
        brighter = get_job_preview_png.sync_detailed(
            job_id, client=client, exposure=1.5, if_none_match=png_tag
        )
        expect(brighter, 200, File, "preview.png at another exposure")
        summary["etags"] = [exr_tag, png_tag, brighter.headers["etag"]]

        workers = expect(list_workers.sync_detailed(client=client), 200, None, "workers")
        assert sum(w.samples_done for w in workers.workers) >= done.samples_done, workers.to_dict()
        summary["workers"] = [w.name for w in workers.workers]

        # A job cancelled before it could finish, then deleted.
        long_id = submit(client, scene, "cancelled", width=64, height=64, spp=1 << 16)
        cancelled = expect(cancel_job.sync_detailed(long_id, client=client), 200, JobView, "cancel")
        assert cancelled.state == JobState.CANCELLED, cancelled.state
        expect(delete_job.sync_detailed(long_id, client=client), 204, None, "delete")
        gone = get_job.sync_detailed(long_id, client=client)
        error = expect(gone, 404, ErrorBody, "the deleted job")
        assert error.error.code == "not_found", error.to_dict()

        # A refused submission comes back as the contract's error body.
        bad = submit_job.sync_detailed(
            client=client,
            body=SubmitJobBody(
                scene=File(payload=scene, file_name="cornell.gltf"),
                settings=JobSettings(width=32, height=32, spp=1, rr="1.5"),
            ),
        )
        error = expect(bad, 422, ErrorBody, "a bad rr")
        assert error.error.code == "invalid_settings", error.to_dict()

    (out_dir / "summary.json").write_text(json.dumps(summary))
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
