"""Who gets a person two tracks could claim, by appearance and by where the tracks' regions lie: the rules of the
tracker's steps 1 and 4 (glimpse.ingest.tracker) that move an observation from one track, or from the new people,
to another, or take it from a track that another claims better. Each changes its dicts and lists in place."""

from __future__ import annotations

from glimpse.ingest.appearance import appearance_distance, comparable
from glimpse.ingest.blazepose import box_iou
from glimpse.ingest.observation import Observation, Track


def _expected_over(track: Track, observation: Observation) -> bool:
    """Whether the region where ``track`` expects its person this frame overlaps the observation's box."""
    return box_iou(track.predicted_region().box()[None], observation.box[None])[0, 0] > 0


def return_refound(followed: dict[int, Observation], live: list[Track], margin: float) -> None:
    """Whom a track missing until this frame found in its region (a region left where its person was last seen,
    which someone else may have walked into) goes to a track seen in the last frame that found nobody, whose
    predicted region overlaps them and whom they look like better by more than ``margin`` (appearance distance):
    that track's person, whom its own region, over them and someone else, did not show the landmark model alone.
    ``followed``: track index -> what it found this frame; ``live``: the tracks that looked."""
    empty = [t for t in live if t.missing == 0 and t.index not in followed]
    for track in [t for t in live if t.missing and t.index in followed]:
        observation = followed[track.index]
        best, best_gain = None, margin
        for other in empty:
            if not _expected_over(other, observation) or not comparable(other.look, observation.look):
                continue
            gain = appearance_distance(track.look, observation.look) - appearance_distance(other.look,
                                                                                            observation.look)
            if gain > best_gain:
                best, best_gain = other, gain
        if best is not None:
            del followed[track.index]
            followed[best.index] = observation
            empty.remove(best)


def reclaim(fresh: list[Observation], followed: dict[int, Observation], tracks: list[Track], margin: float) -> None:
    """A new observation (of ``fresh``) that overlaps what a track followed this frame and looks like that track
    better, by more than ``margin``, is the track's person: the followed fit had slid half onto someone else (a
    crossing). The track takes it (removed from ``fresh``); the followed fit is dropped. ``tracks``: every track."""
    by_index = {t.index: t for t in tracks}
    for observation in list(fresh):
        best, best_gain = None, margin
        for index, current in followed.items():
            look = by_index[index].look
            apart = box_iou(observation.box[None], current.box[None])[0, 0] == 0
            if apart or not comparable(look, observation.look):
                continue
            gain = appearance_distance(look, current.look) - appearance_distance(look, observation.look)
            if gain > best_gain:
                best, best_gain = index, gain
        if best is not None:
            followed[best] = observation
            fresh[:] = [other for other in fresh if other is not observation]


def drop_lookalikes(followed: dict[int, Observation], live: list[Track], margin: float) -> None:
    """What a track found in its region is not its person when they look like another live track better, by more
    than ``margin`` (appearance distance), and that track's predicted region overlaps them: the region slid onto,
    or half onto, the person another track follows or lost (two people crossing, one hidden behind the other).
    Kept, the fit moves the track's running appearance towards the other person's until the tracker can no longer
    tell them apart. The track counts as unseen here and looks behind the people found (the tracker's step 2);
    its find is only dropped, not given to the other track. ``followed``: track index -> what it found this frame;
    ``live``: the tracks that looked."""
    for track in [t for t in live if t.index in followed]:
        observation = followed[track.index]
        own = appearance_distance(track.look, observation.look)
        for other in live:
            if other.index == track.index or not comparable(other.look, observation.look):
                continue
            if _expected_over(other, observation) and appearance_distance(other.look, observation.look) + margin < own:
                del followed[track.index]
                break
