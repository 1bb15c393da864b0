"""Checks of the statements in docs/conventions.md marked (tested) that no other test covers."""

from __future__ import annotations

from pathlib import Path

from workers.handmodel.keypoints import (
    FINGERTIP_ORDER,
    FREIHAND_FROM_MANO,
    KEYPOINT_NAMES,
    MANO_JOINT_NAMES,
    MANO_PARENTS,
    SKELETON_EDGES,
    SPARSE_KEYPOINTS,
)

DOC = Path(__file__).resolve().parents[1] / "docs" / "conventions.md"


def test_freihand_order_is_as_documented():
    assert "0 wrist; 1-4 thumb (base to tip); 5-8 index; 9-12 middle" in DOC.read_text().replace("\n  ", " ")
    fingers = ["thumb", "index", "middle", "ring", "pinky"]
    assert KEYPOINT_NAMES[0] == "wrist"
    for f, finger in enumerate(fingers):
        names = KEYPOINT_NAMES[1 + 4 * f: 5 + 4 * f]
        assert all(n.startswith(finger) for n in names) and names[-1] == f"{finger}_tip"
    assert [KEYPOINT_NAMES[k] for k in SPARSE_KEYPOINTS] == ["wrist"] + [f"{f}_tip" for f in fingers]


def test_mano_to_freihand_mapping_follows_the_names():
    joint_or_tip = list(MANO_JOINT_NAMES) + [f"{f}_tip" for f in FINGERTIP_ORDER]
    for k, source in enumerate(FREIHAND_FROM_MANO):
        finger = KEYPOINT_NAMES[k].split("_")[0]
        assert joint_or_tip[source].startswith(finger), (k, KEYPOINT_NAMES[k], joint_or_tip[source])
    # Base to tip within each finger: MANO joints increase along the chain.
    for f in range(5):
        chain = FREIHAND_FROM_MANO[1 + 4 * f: 4 + 4 * f]
        assert MANO_PARENTS[chain[1]] == chain[0] and MANO_PARENTS[chain[2]] == chain[1]


def test_skeleton_edges_connect_each_finger_to_the_wrist():
    assert len(SKELETON_EDGES) == 20
    for parent, child in SKELETON_EDGES:
        assert parent == 0 if child % 4 == 1 else parent == child - 1
