"""COLMAP's steps of :func:`cylindersplat.data.poses.sfm.run_sfm`, run as a separate process.

COLMAP ends the process on some failures (a full temporary disk or a file-size limit makes it abort with a C++
stack trace); in a child of its own that is an exit status the caller turns into one line, and the caller still
removes the temporary folder. Run as ``python _colmap_worker.py JOB.json``; it imports pycolmap only (no torch,
so it starts in a moment). It prints ``stage: ...`` lines as it goes and ``error: TYPE: MESSAGE`` before exiting
with status 3 on a Python-level failure; the models go to ``<work>/sparse/<index>`` (COLMAP binary).

The job: ``work`` (temporary folder), ``folder`` (the panoramas), ``groups`` (``[[width, height, [names]], ...]``:
one EQUIRECTANGULAR camera per image size), ``matcher`` (exhaustive or sequential), ``threads``, ``seed``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def _say(line: str) -> None:
    print(line, flush=True)


def run(job: dict) -> None:
    import pycolmap

    try:
        pycolmap.logging.minloglevel = 3  # our own lines say the progress; COLMAP's fatal errors still show
    except AttributeError:
        pass
    work, folder, threads = Path(job["work"]), Path(job["folder"]), job["threads"]
    pycolmap.set_random_seed(job["seed"])
    database = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "EQUIRECTANGULAR"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    for width, height, names in job["groups"]:  # each call makes one camera: one per image size
        _say(f"stage: extracting the features of {len(names)} panoramas of {width}x{height}")
        pycolmap.extract_features(database, folder, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    _say(f"stage: matching ({job['matcher']})")
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    if job["matcher"] == "exhaustive":
        pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
    else:
        pycolmap.match_sequential(database, matching_options=matching, device=pycolmap.Device.cpu)
    _say("stage: incremental mapping")
    options = pycolmap.IncrementalPipelineOptions()
    options.mapper.init_max_forward_motion = 1.0  # a panorama walk moves along the "optical axis": fine here
    options.min_model_size = 2
    options.num_threads = threads
    options.ba_refine_focal_length = options.ba_refine_principal_point = options.ba_refine_extra_params = False
    out = work / "sparse"
    out.mkdir(exist_ok=True)
    models = pycolmap.incremental_mapping(database, folder, out, options)
    for index, model in models.items():
        (out / str(index)).mkdir(exist_ok=True)
        model.write(str(out / str(index)))
    _say(f"stage: done ({len(models)} models)")


def main() -> int:
    try:
        run(json.loads(Path(sys.argv[1]).read_text()))
    except Exception as exc:  # noqa: BLE001 - reported to the parent as one line
        _say(f"error: {type(exc).__name__}: {' '.join(str(exc).split())}")
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
