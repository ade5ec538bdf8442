"""Atomic publication of stage outputs."""


from glimpse.pipeline.runner import _recover_interrupted_swap, publish


def test_publish_replaces_the_old_output(tmp_path):
    final, tmp = tmp_path / "01_sfm", tmp_path / "new"
    final.mkdir(); (final / "manifest.json").write_text("old")
    tmp.mkdir(); (tmp / "manifest.json").write_text("new")
    publish(tmp, final)
    assert (final / "manifest.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["01_sfm"]


def test_a_swap_killed_between_renames_restores_the_old_output(tmp_path):
    final = tmp_path / "01_sfm"
    old = tmp_path / ".01_sfm.old-123"
    old.mkdir(); (old / "manifest.json").write_text("old")  # state after the first rename only
    _recover_interrupted_swap(final)
    assert (final / "manifest.json").read_text() == "old"
    assert not old.exists()
