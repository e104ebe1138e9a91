"""The topics of the ROS 2 bag that birlg-export writes (pipeline/tools/export.py): not
artefacts of a run, but named below the stages because a run's summary tells users which
of them to deploy."""

LEARNED = "/birlg/learned_paths"  # on the adaptive graph, one Path per start
LEARNED_REF = "/birlg/learned_paths_ref"  # on the reference roadmap
DEMOS = "/birlg/demos"
PEOPLE = "/birlg/people"
