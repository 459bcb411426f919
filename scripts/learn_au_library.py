"""Learn faceanim's built-in action-unit displacements from real scans (thesis 5.5.3).

    python scripts/learn_au_library.py ../shared/data/facewarehouse-tester1

Each action unit is learned from the FaceWarehouse expression that performs it (the table
below: the dataset's expression order), keeping only that AU's control points. Writes
src/faceanim/data/au_displacements.json (displacements in the source's normalised frame:
x to the subject's left eye, y up, z forward; units of inter-ocular distance for the upper
face and of mouth width for the lower face).
"""

import argparse
import sys
from pathlib import Path

from faceanim.face.face import landmarks_478
from faceanim.face.landmarks import detect_landmarks
from faceanim.io.files import write_json
from faceanim.io.meshio import load_mesh
from faceanim.rig.facs import default_library
from faceanim.rig.transfer import ActionUnitModel, learn_expression

# FaceWarehouse's 19 expressions (pose_1..pose_19) and the AUs each one shows
FACEWAREHOUSE_EXPRESSIONS = {
    1: "mouth stretch", 2: "smile", 3: "brow lower", 4: "brow raise", 5: "anger", 6: "jaw left",
    7: "jaw right", 8: "jaw forward", 9: "mouth left", 10: "mouth right", 11: "dimpler",
    12: "chin raiser", 13: "lip puckerer", 14: "lip funneler", 15: "sadness", 16: "lip roll",
    17: "grin", 18: "cheek blowing", 19: "eyes closed",
}
AU_SOURCE = {1: 4, 2: 4, 4: 3, 5: 4, 6: 17, 7: 5, 9: 5, 10: 17, 12: 2, 14: 11, 15: 15, 16: 17, 17: 12,
             18: 13, 20: 17, 22: 14, 23: 5, 24: 16, 25: 17, 26: 1, 27: 1, 28: 16, 43: 19}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path, help="folder with pose_0.obj (neutral) .. pose_19.obj")
    ap.add_argument("-o", "--output", type=Path,
                    default=Path(__file__).resolve().parents[1] / "src/faceanim/data/au_displacements.json")
    args = ap.parse_args(argv)
    lib = default_library()
    neutral = load_mesh(args.data / "pose_0.obj")
    lm = landmarks_478(neutral, detect_landmarks(neutral))
    model = ActionUnitModel(about=(
        f"AU displacements learned by scripts/learn_au_library.py from {args.data.name} (FaceWarehouse, "
        "one registered person; research use). Per AU: the expression it was learned from and its "
        "control points' displacements in the source's normalised frame."))
    cache = {}
    for au, pose in sorted(AU_SOURCE.items()):
        if pose not in cache:
            cache[pose] = learn_expression(neutral, load_mesh(args.data / f"pose_{pose}.obj"), lm, library=lib)
        sample = cache[pose].subset([p for p in lib.action_unit(au).points if p in cache[pose].names])
        sample.source = f"{args.data.name}/pose_{pose} ({FACEWAREHOUSE_EXPRESSIONS[pose]})"
        model.samples[au] = sample
        print(f"AU{au:<3d} {lib.action_unit(au).name:<22s} <- pose_{pose} ({FACEWAREHOUSE_EXPRESSIONS[pose]})")
    write_json(args.output, model.to_dict())
    print(f"wrote {args.output}")


if __name__ == "__main__":
    sys.exit(main())
