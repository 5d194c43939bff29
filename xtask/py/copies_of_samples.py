"""Copies of the two shared CMU samples under new subject numbers, for
measuring `cargo xtask train` on a larger dataset (docs/training.md, "The
budget"): with the two archives themselves, `--copies 16` gives 17 times
the samples' frames, takes and (about) windows.

Copy k (1-based) renumbers each subject of either archive to
145 + (k - 1) * S + its index among the S subjects (past CMU's last, 143),
the same number in both archives, so a take in both is still one take. An
ASF gets a `#` comment naming its copy and a BVH's `Frame Time` k more
trailing zeros (the same value): no two copies are the same bytes (the
dataset keeps one file per content). Beside the folders, `fps.csv` gives
each copied take its original's rate (CMU's `trials.csv`) and
`categories.csv` its original's category (`data/cmu-categories.csv`).

    python3 xtask/py/copies_of_samples.py --copies 16 --out /tmp/x17
    cargo xtask dataset --source ../shared/cmu/cmu-bvh-sample.zip \
        --source ../shared/cmu/cmu-asfamc-sample.zip \
        --source /tmp/x17/bvh --source /tmp/x17/asfamc \
        --fps-table /tmp/x17/fps.csv --categories /tmp/x17/categories.csv \
        --out /tmp/x17/ds

About 4.8 GB for 16 copies.
"""

import argparse
import csv
import os
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--copies", type=int, default=16)
    p.add_argument("--out", required=True)
    p.add_argument("--shared", default=os.path.join(ROOT, "..", "shared", "cmu"))
    a = p.parse_args()
    with open(os.path.join(a.shared, "trials.csv"), newline="") as f:
        fps = {r["take"]: r["fps"] for r in csv.DictReader(f)}
    with open(os.path.join(ROOT, "data", "cmu-categories.csv"), newline="") as f:
        cats = {r["take"]: r["category"] for r in csv.DictReader(f)}
    amc = zipfile.ZipFile(os.path.join(a.shared, "cmu-asfamc-sample.zip"))
    bvh = zipfile.ZipFile(os.path.join(a.shared, "cmu-bvh-sample.zip"))
    names = [n for n in amc.namelist() + bvh.namelist() if n.endswith((".amc", ".bvh"))]
    subjects = sorted({os.path.basename(n).split("_")[0] for n in names})
    if 145 + a.copies * len(subjects) > 999:
        raise SystemExit("too many copies for three-digit subject numbers")
    rows = {}  # new take id -> (fps, category)

    def write(folder, name, data):
        os.makedirs(folder, exist_ok=True)
        with open(os.path.join(folder, name), "wb") as f:
            f.write(data)

    for k in range(1, a.copies + 1):
        number = {s: str(145 + (k - 1) * len(subjects) + i) for i, s in enumerate(subjects)}
        for archive, kind in ((amc, "asfamc"), (bvh, "bvh")):
            for n in archive.namelist():
                base = os.path.basename(n)
                stem, ext = os.path.splitext(base)
                if ext not in (".amc", ".asf", ".bvh"):
                    continue
                subject = stem.split("_")[0]
                new = number[subject]
                folder = os.path.join(a.out, kind, new)
                data = archive.read(n)
                if ext == ".asf":
                    write(folder, f"{new}.asf", data + f"\n# copy {k} as subject {new}\n".encode())
                    continue
                trial = stem.split("_")[1]
                if ext == ".bvh":
                    i = data.index(b"Frame Time:")
                    j = data.index(b"\n", i)
                    data = data[:j].rstrip(b"\r") + b"0" * k + data[j:]
                write(folder, f"{new}_{trial}{ext}", data)
                rows[f"{new}_{trial}"] = (fps[stem], cats[stem])
    with open(os.path.join(a.out, "fps.csv"), "w") as f:
        f.write("take,fps\n" + "".join(f"{t},{r[0]}\n" for t, r in sorted(rows.items())))
    with open(os.path.join(a.out, "categories.csv"), "w") as f:
        f.write("take,category\n" + "".join(f"{t},{r[1]}\n" for t, r in sorted(rows.items())))
    print(f"{a.copies} copies of {len(subjects)} subjects, {len(rows)} takes, in {a.out}")


if __name__ == "__main__":
    main()
