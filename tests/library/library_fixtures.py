"""Which real takes the library tests build their library from."""

#: Bandai clips on the model skeleton (a walk, a run, raising both hands).
BANDAI = (
    "dataset-2_walk_active_001.bvh.gz",
    "dataset-2_run_active_001.bvh.gz",
    "dataset-2_raise-up-both-hands_active_001.bvh.gz",
)
#: A CMU take on the 100-joint Character Creator rig at 60 fps.
CMU_TAKE = "002_02.bvh.gz"
#: Another take of the walk, not in the library.
HELD_OUT = "dataset-2_walk_active_003.bvh.gz"
