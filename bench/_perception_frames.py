"""``bench/perception.py frames``: the train frames a fair photo set may be made from, per
fraction and CV fold (issue 21): nothing outside the arm's real subset (its labels are all the arm
is given) and nothing a CV fold holds out (the fold would be scored on its own textures)."""
from __future__ import annotations

from pathlib import Path

from roadtwin_core.errors import RoadtwinError

from _perception_cv import fold_frame_lists
from _perception_data import load_frames, parse_size


def cmd_frames(args, log=print) -> dict[str, list[str]]:
    """Per fraction and CV fold, the train frames a fair photo library may be built from (stems,
    one a line, sorted): nothing outside the arm's subset, nothing a fold holds out."""
    if args.cv_folds == 1 or args.cv_folds < 0:
        raise RoadtwinError(f"--cv-folds {args.cv_folds}: give 2 or more folds (0: the fraction lists only)")
    if not (args.train or args.real):
        raise RoadtwinError("give --real DIR (with train/), or --train DIR")
    train = Path(args.train) if args.train else Path(args.real) / "train"
    real = load_frames(train, parse_size(args.size), args.limit_frames)
    lists = fold_frame_lists(real, args.fractions, args.cv_folds, args.subset_seed)   # every error before a write
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, stems in lists.items():
        tmp = out / f".{name}.txt.tmp"
        tmp.write_text("".join(f"{s}\n" for s in stems))
        tmp.replace(out / f"{name}.txt")
        log(f"{out / name}.txt: {len(stems)} of the {len(real.stems)} train frames")
    return lists
