"""Structure from motion for `ins-cli data sfm`, through pycolmap (COLMAP's Python bindings).

Writes a COLMAP workspace the INS-rs COLMAP reader loads: OUT/images/ (copies of the photos)
and OUT/sparse/0/ (binary model of the largest reconstruction). Prints one line per stage and,
last, one JSON line with the summary (prefixed `SUMMARY `).

Usage: python sfm.py --images DIR --out WS [--camera-model SIMPLE_RADIAL] [--threads N]
"""
import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import pycolmap

EXTENSIONS = {".png", ".jpg", ".jpeg"}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--images", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--camera-model", default="SIMPLE_RADIAL")
    ap.add_argument("--threads", type=int, default=-1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    pycolmap.set_random_seed(args.seed)

    names = sorted(p.name for p in args.images.iterdir() if p.suffix.lower() in EXTENSIONS)
    if not names:
        sys.exit(f"{args.images}: no PNG or JPEG photos")
    ws = args.out
    img_dir = ws / "images"
    img_dir.mkdir(parents=True, exist_ok=True)
    for n in names:
        shutil.copy2(args.images / n, img_dir / n)
    db = ws / "database.db"
    if db.exists():
        db.unlink()
    timings = {}

    def stage(name, t0):
        timings[name] = time.perf_counter() - t0
        print(f"  {name}: {timings[name]:.1f} s", flush=True)

    print(f"sfm: {len(names)} photos, pycolmap {pycolmap.__version__}", flush=True)
    t0 = time.perf_counter()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = args.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = args.threads
    extraction.use_gpu = False
    pycolmap.extract_features(db, img_dir, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction,
                              device=pycolmap.Device.cpu)
    stage("features", t0)

    t0 = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = args.threads
    matching.use_gpu = False
    pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
    stage("matching", t0)

    t0 = time.perf_counter()
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = args.threads
    options.random_seed = args.seed
    options.ba_global_function_tolerance = 1e-6
    tmp = Path(tempfile.mkdtemp(prefix="mapper_", dir=ws))
    recs = pycolmap.incremental_mapping(db, img_dir, tmp, options=options)
    stage("mapping", t0)
    if not recs:
        shutil.rmtree(tmp)
        sys.exit("no reconstruction: the photos did not match (too little overlap or texture)")
    best = max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    sparse0 = ws / "sparse" / "0"
    if sparse0.exists():
        shutil.rmtree(sparse0)
    sparse0.mkdir(parents=True)
    best.write_binary(sparse0)
    shutil.rmtree(tmp)
    registered = {best.image(i).name for i in best.reg_image_ids()}
    summary = {
        "photos": len(names),
        "registered": len(registered),
        "unregistered": sorted(set(names) - registered),
        "points": best.num_points3D(),
        "reprojection_error_px": best.compute_mean_reprojection_error(),
        "cameras": [{"model": c.model.name, "width": c.width, "height": c.height,
                     "params": [float(x) for x in c.params]} for c in best.cameras.values()],
        "seconds": timings,
        "pycolmap": pycolmap.__version__,
    }
    print("SUMMARY " + json.dumps(summary), flush=True)


if __name__ == "__main__":
    main()
