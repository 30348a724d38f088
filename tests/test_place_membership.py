"""A device's place as its checkpoint records it: read back as written, nothing recorded in a
checkpoint written before places were, a record that contradicts itself refused; the copies'
tag of a device the same in every edge process, and another for each map the edge starts it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from edge_mapper.place_membership import (
    FOLLOWED,
    OFFERED,
    OFFERED_AT,
    OFFERED_BY,
    RUN,
    PlaceMembership,
    run_after,
    source_of,
)
from twinslam.slam.back_end.foreign_keyframes import MAX_SOURCES


def test_a_place_is_read_back_as_it_was_written() -> None:
    record = PlaceMembership("ar1", {"ar3": 2, "ar1": 5}, run=3,
                             offered={"ar3": {17: 4, 9: 6}, "ar1": {2: 1}})
    assert PlaceMembership.read(record.arrays()) == record
    assert PlaceMembership.read(PlaceMembership().arrays()) == PlaceMembership()


def test_a_checkpoint_without_a_place_is_a_map_of_its_own() -> None:
    assert PlaceMembership.read({"version": np.array(4)}) == PlaceMembership()


def test_a_record_written_before_runs_were_counted_is_a_first_map() -> None:
    arrays = PlaceMembership("ar1", {"ar3": 2}).arrays()
    del arrays[RUN]
    assert PlaceMembership.read(arrays) == PlaceMembership("ar1", {"ar3": 2}, run=0)


def test_each_map_of_a_device_has_a_tag_of_its_own() -> None:
    """A device's first map keeps the tag its name alone gives (copies checkpointed before
    maps were counted keep theirs); its later maps each get another one."""
    tags = [source_of("ar1", run) for run in range(4)]
    assert len(set(tags)) == 4 and tags[0] == source_of("ar1")
    with pytest.raises(ValueError, match="counts from 0"):
        source_of("ar1", -1)


def test_the_next_maps_run_is_one_past_the_map_set_aside(tmp_path: Path) -> None:
    """A reclaimed map's checkpoint (``FILE.reclaimed``) names its run; none, or one that
    cannot be read, counts as the first map."""
    aside = tmp_path / "edge.ar1.npz.reclaimed"
    assert run_after(aside) == 0
    with aside.open("wb") as f:
        np.savez(f, **PlaceMembership("ar2", {}, run=2).arrays())
    assert run_after(aside) == 3
    aside.write_bytes(b"not a checkpoint")
    assert run_after(aside) == 1


def test_a_record_written_before_offers_were_kept_offers_nothing() -> None:
    arrays = PlaceMembership("ar1", {"ar3": 2}, offered={"ar3": {5: 1}}).arrays()
    for name in (OFFERED_BY, OFFERED, OFFERED_AT):
        del arrays[name]
    assert PlaceMembership.read(arrays) == PlaceMembership("ar1", {"ar3": 2})


def test_a_record_whose_offers_disagree_in_length_is_refused() -> None:
    arrays = PlaceMembership("ar1", {}, offered={"ar3": {5: 1, 6: 2}}).arrays()
    arrays[OFFERED_AT] = arrays[OFFERED_AT][:1]
    with pytest.raises(ValueError, match="2 lenders, 2 keyframes and 1 slots"):
        PlaceMembership.read(arrays)
    arrays = PlaceMembership("ar1", {}, offered={"ar3": {5: 1, 6: 2}}).arrays()
    arrays[OFFERED_BY] = arrays[OFFERED_BY][:1]
    with pytest.raises(ValueError, match="1 lenders, 2 keyframes and 2 slots"):
        PlaceMembership.read(arrays)


def test_a_record_with_a_loop_count_too_few_is_refused() -> None:
    arrays = PlaceMembership("ar1", {"ar1": 5, "ar3": 2}).arrays()
    arrays[FOLLOWED] = arrays[FOLLOWED][:1]
    with pytest.raises(ValueError, match="2 lenders and 1 loop counts"):
        PlaceMembership.read(arrays)


def test_a_devices_tag_is_the_same_in_another_process() -> None:
    """Python salts its own string hashes per process: the tag must not use them."""
    names = ["ar1", "ar2", "/fleet/phone_17"]
    other = subprocess.run(
        [sys.executable, "-c", "from edge_mapper.place_membership import source_of; "
         f"print([source_of(n) for n in {names!r}])"],
        capture_output=True, text=True, timeout=120, check=True)
    tags = [source_of(n) for n in names]
    assert other.stdout.strip() == str(tags)
    assert all(0 <= t < MAX_SOURCES for t in tags) and len(set(tags)) == 3
