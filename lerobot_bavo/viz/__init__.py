"""`bavo-view`: BAVO episodes (datasets and `bavo-eval` rollouts) in rerun.

`episode.EpisodeData` holds one episode as arrays (`episode.load_dataset_episode` reads it from a
dataset, `recorder.RolloutRecorder` from a running rollout); `entities` maps a frame to the rerun
archetypes drawn for it (small pure functions; its docstring lists every entity path); `log` writes
them to an `.rrd` file or a viewer; `cli` is the command line.
"""
