"""pycolmap (COLMAP 4, CPU) as the structure-from-motion peer of benches/sfm_vs_colmap.rs.

Runs SIFT extraction (at the same largest side and feature cap as geostride: 2000 px, 8192)
and exhaustive matching once on the named images of a folder, then the incremental and the
global (GLOMAP) mapper with each seed, and prints one JSON object: the extraction's and the
matching's seconds, and per mapper and seed its seconds, registered images, points, mean
reprojection error and each registered image's camera centre (model frame). A run's total time
is extraction + matching + its mapping.

Pairs: exhaustive, or with `--priors FILE` (CSV `name,x,y,z`, metres in one Cartesian frame: the
flight's measured camera centres) COLMAP's spatial matcher over each image's `--neighbours`
nearest (horizontally), the centres written to the database as pose priors.

Camera: `--camera guess` lets COLMAP start from its own guess (EXIF, else 1.2 times the longer
side) and refine it (one SIMPLE_RADIAL camera, COLMAP's default; the principal point held, as
COLMAP does by default); `--camera fx,fy,cx,cy` is one PINHOLE camera with that K (geostride's
pixel convention: 0.5 is added for COLMAP's) held fixed; `--camera-refine fx,fy,cx,cy` is an
OPENCV camera from that K with its focal lengths and distortion refined.
"""

import argparse
import csv
import json
import os
import shutil
import sys
import tempfile
import time

import pycolmap


def mapping(db, images, work, mapper, seed, refine, threads):
    """One mapper run on the database: its largest model as a dict, and its seconds."""
    out = os.path.join(work, f"sparse-{mapper}-{seed}")
    os.makedirs(out)
    pycolmap.set_random_seed(seed)
    t = time.perf_counter()
    if mapper == "incremental":
        opts = pycolmap.IncrementalPipelineOptions()
        opts.random_seed = seed
        opts.num_threads = threads
        opts.ba_refine_focal_length = refine
        opts.ba_refine_extra_params = refine
        opts.ba_refine_principal_point = False
        models = pycolmap.incremental_mapping(db, images, out, options=opts)
    else:
        opts = pycolmap.GlobalPipelineOptions()
        opts.random_seed = seed
        opts.num_threads = threads
        if not refine:
            opts.mapper.bundle_adjustment.refine_focal_length = False
            opts.mapper.bundle_adjustment.refine_extra_params = False
        models = pycolmap.global_mapping(db, images, out, options=opts)
    seconds = time.perf_counter() - t
    run = {"mapper": mapper, "seed": seed, "mapping_s": seconds, "registered": 0}
    if models:
        r = max(models.values(), key=lambda m: m.num_reg_images())
        cam = next(iter(r.cameras.values()))
        run.update(
            registered=r.num_reg_images(),
            points=r.num_points3D(),
            mean_reprojection_px=r.compute_mean_reprojection_error(),
            camera={"model": str(cam.model), "params": list(cam.params)},
            centres={
                img.name: list(img.projection_center())
                for img in r.images.values()
                if img.has_pose
            },
        )
    return run


def write_priors(db_path, priors):
    """The measured centres (name -> (x, y, z)) as Cartesian pose priors of their images."""
    db = pycolmap.Database.open(db_path)
    try:
        for image in db.read_all_images():
            if image.name not in priors:
                continue
            prior = pycolmap.PosePrior()
            prior.corr_data_id = pycolmap.data_t(
                sensor_id=pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=image.camera_id),
                id=image.image_id,
            )
            prior.position = priors[image.name]
            prior.coordinate_system = pycolmap.PosePriorCoordinateSystem.CARTESIAN
            db.write_pose_prior(prior)
    finally:
        db.close()


def read_priors(path):
    with open(path, newline="") as f:
        return {r[0]: [float(v) for v in r[1:4]] for r in csv.reader(f) if r and r[0] != "name"}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("images", help="folder of the images")
    ap.add_argument("names", nargs="+", help="image file names in the folder")
    ap.add_argument("--mappers", default="incremental,global")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--camera", default="guess")
    ap.add_argument("--camera-refine", default=None)
    ap.add_argument("--max-image-size", type=int, default=2000)
    ap.add_argument("--max-features", type=int, default=8192)
    ap.add_argument("--threads", type=int, default=-1)
    ap.add_argument("--priors", default=None)
    ap.add_argument("--neighbours", type=int, default=8)
    a = ap.parse_args()

    work = tempfile.mkdtemp(prefix="pycolmap-")
    try:
        db = os.path.join(work, "db.db")
        reader = pycolmap.ImageReaderOptions()
        refine = True
        k = a.camera_refine or (None if a.camera == "guess" else a.camera)
        if k is not None:
            fx, fy, cx, cy = (float(v) for v in k.split(","))
            refine = a.camera_refine is not None
            if refine:
                reader.camera_model = "OPENCV"
                reader.camera_params = f"{fx},{fy},{cx + 0.5},{cy + 0.5},0,0,0,0"
            else:
                reader.camera_model = "PINHOLE"
                reader.camera_params = f"{fx},{fy},{cx + 0.5},{cy + 0.5}"
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = a.threads
        extraction.max_image_size = a.max_image_size
        extraction.sift.max_num_features = a.max_features
        cpu = pycolmap.Device.cpu
        t0 = time.perf_counter()
        pycolmap.extract_features(
            db,
            a.images,
            image_names=a.names,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=extraction,
            device=cpu,
        )
        features_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = a.threads
        if a.priors:
            write_priors(db, read_priors(a.priors))
            pairing = pycolmap.SpatialPairingOptions()
            pairing.max_num_neighbors = a.neighbours
            pairing.max_distance = 1e9
            pairing.num_threads = a.threads
            pycolmap.match_spatial(
                db, matching_options=matching, pairing_options=pairing, device=cpu
            )
        else:
            pycolmap.match_exhaustive(db, matching_options=matching, device=cpu)
        matching_s = time.perf_counter() - t1
        runs = [
            mapping(db, a.images, work, m, int(seed), refine, a.threads)
            for m in a.mappers.split(",")
            for seed in a.seeds.split(",")
        ]
        print(json.dumps({"features_s": features_s, "matching_s": matching_s, "runs": runs}))
        return 0
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
