"""What the Train screen checks before a run: whether the chosen recordings hold the inputs the chosen
observation needs (camera frames for images; the twin task objects' state for state), said with the key that
changes it -- the same conditions `factr2 train` refuses in policies/data/dataset.py."""

from __future__ import annotations


def recording_inputs(files) -> dict:
    """Per recording file: (has camera frames, has the PRIVILEGED twin object state). Blocking: a worker."""
    import warnings

    from hardware.recording import schemas as S
    from hardware.recording.reader import Recording

    out = {}
    for f in sorted(set(files)):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = Recording(f)
            out[f] = (bool(r.cameras), S.TOPIC_TASK_OBJECTS in r.topics)
        except Exception:  # noqa: BLE001 -- the Episodes rows already say why a file is unreadable
            continue
    return out


def observation_problem(files, inputs: dict, observation: str) -> str:
    """Why recordings `files` cannot train with this observation, in words with the key to press ("" when
    they can): images need camera frames in every recording, state the twin task objects' state."""
    from policies.data.privileged import uses_images, uses_objects

    files = sorted(set(files))
    no_cam = [f for f in files if not inputs.get(f, (True, True))[0]]
    no_obj = [f for f in files if not inputs.get(f, (True, True))[1]]
    n = len(files)
    if uses_images(observation) and no_cam:
        fix = ("press i for obs state" if not no_obj else
               "record with cameras, or collect on a twin task for obs state")
        return f"obs images: {len(no_cam)} of {n} recording(s) have no camera frames -- {fix}"
    if uses_objects(observation) and no_obj:
        fix = "press i for obs images" if not no_cam else "collect them on a twin task (factr2 collect)"
        return (f"obs state: {len(no_obj)} of {n} recording(s) have no twin object state (recorded by "
                f"`factr2 collect` on a twin task) -- {fix}")
    return ""
