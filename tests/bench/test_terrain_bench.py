"""bench.terrain: the per-tile physics profile runs on a small terrain and its table reads its numbers."""

from __future__ import annotations

from pathlib import Path

import pytest

from dls_quadruped.bench.terrain import markdown, run


def test_terrain_bench_profiles_every_type_and_the_plane():
    result = run("rough", rows=[0], steps=20)
    kinds = [t["type"] for t in result["tiles"]]
    assert kinds == ["flat", "rugged", "slope_up", "slope_down", "boxes", "stairs_up", "stairs_down"]
    for r in (result["plane"], *result["tiles"]):
        # MuJoCo's timers are parts of the step: together they cannot exceed it
        parts = r["pos_kinematics_us"] + r["col_broad_us"] + r["col_narrow_us"] + r["constraint_us"]
        assert 0 < parts <= r["step_us"] * 1.05
        assert r["contacts"] >= 4  # four feet on the ground
    table = markdown(result).splitlines()
    assert len(table) == 2 + 1 + len(kinds) and table[2].startswith("| plane |")
    assert f"| boxes ({result['ngeom']} geoms) |" in markdown(result)


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_terrain_ab_swaps_in_the_given_terrain_module(tmp_path):
    """The A/B bench builds rough with the module it is given: a copy of sim/terrain.py whose
    build_scene marks its terrain proves the swap (and that the current one is restored)."""
    import dls_quadruped.envs.managers.scene as scene_module
    from dls_quadruped.bench import terrain_ab
    from dls_quadruped.sim import terrain as current

    src = Path(current.__file__).read_text().replace("    return model, terrain\n",
                                                     "    terrain.marker = 'baseline'\n    return model, terrain\n")
    path = tmp_path / "baseline_terrain.py"
    path.write_text(src)
    module = terrain_ab.load_terrain_module(path)
    env = terrain_ab.make_env("rough", 4, module)
    try:
        assert getattr(env.scene.terrain, "marker", None) == "baseline"
    finally:
        env.close()
    assert scene_module.build_scene is current.build_scene
