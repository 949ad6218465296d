"""Step 2's two classifiers on scenario C (design §10; the paper's section 3.2: "Linear and statistical Bayes
classification can achieve correct classification of ca. 97% of foreground tiles"): the thresholds (the linear
classifier, (12 grey levels, 0.1 tile heights)) and a Bayes classifier trained on the simulation's exact labels.

Tiles are labelled by the exact label images: foreground when at least a tenth of the tile's pixels show the
person, background when none does and the robot's tiles do not cover it. The classifier is trained on every other
frame with the person in view and tested on the frames in between; the light dims 20 % during them (both use the
light's gain). Reported: the share of foreground tiles found, and of background tiles called foreground.

    .venv/bin/python benchmarks/probe_tile_classifier.py
"""

from __future__ import annotations

from importlib import resources

import numpy as np

from depthguard.collision import BayesTileClassifier, ImageCollisionTest, labelled_tiles, light_gain, tile_features
from depthguard_lab.simulation import load_workcell, simulate
from _common import report


def main() -> None:
    with resources.as_file(resources.files("depthguard_lab.simulation").joinpath("scenario_c.yaml")) as path:
        workcell = load_workcell(path)
    reference_frames = list(range(0, 45, 5))
    person_frames = list(range(70, workcell.n_frames, 2))
    frames = {f.index: f for f in simulate(workcell, frames=reference_frames + person_frames)}
    test = ImageCollisionTest(workcell.rig, workcell.robot, workcell.rig.workspace)
    test.set_reference({n: [frames[i].intensity[n] for i in reference_frames] for n in test.names},
                       joints=[frames[i].joints for i in reference_frames])
    person = [k for k, (name, _) in enumerate(workcell.labels()) if name.startswith("worker/")]
    train = person_frames[0::2]
    sets = {"train": ([], []), "test": ([], [])}
    for i in person_frames:
        f = frames[i]
        robot = test.robot_image(f.joints)  # left out: the robot's tiles change by themselves (Table I)
        for c, (name, grid) in enumerate(zip(test.names, test.grids)):
            features = tile_features(f.intensity[name], grid)
            gain = light_gain(features, test.reference[c])
            x, y = labelled_tiles(features, test.reference[c], np.isin(f.label[name], person), grid, gain, robot[c])
            part = sets["train" if i in train else "test"]
            part[0].append(x)
            part[1].append(y)
    x_train, y_train = (np.concatenate(v) for v in sets["train"])
    x_test, y_test = (np.concatenate(v) for v in sets["test"])
    print(f"scenario C, {len(person_frames)} frames with the person (train {len(train)}, test "
          f"{len(person_frames) - len(train)}), four cameras, 64 x 64 tiles: {y_test.sum()} foreground and "
          f"{(~y_test).sum()} background test tiles")
    print(f"{'classifier':32s} {'foreground found':>17s} {'background called foreground':>29s}")
    for thresholds in ((12.0, 0.1), (6.0, 0.05), (4.0, 0.04)):
        linear = np.any(x_test > np.array(thresholds), axis=1)
        print(f"{f'thresholds {thresholds}':32s} {linear[y_test].mean():17.1%} {linear[~y_test].mean():29.2%}")
    for threshold in (0.5, 0.2, 0.05):
        bayes = BayesTileClassifier(threshold).fit(x_train, y_train).foreground(x_test)
        print(f"{f'Bayes, P(foreground) >= {threshold}':32s} {bayes[y_test].mean():17.1%} {bayes[~y_test].mean():29.2%}")


if __name__ == "__main__":
    with report(__file__):
        main()
