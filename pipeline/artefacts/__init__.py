"""Artefact I/O: the MCAP store (store.py), the topic names (topics.py; the export's ROS
bag's in export_topics.py), and the codecs that turn messages back into core objects and
core objects into messages (codec.py)."""

from pipeline.artefacts.store import (
    Artefact,
    ArtefactError,
    ArtefactWriter,
    read_artefact,
    unique_tmp,
    write_artefact,
)

__all__ = ["Artefact", "ArtefactError", "ArtefactWriter", "read_artefact", "unique_tmp",
           "write_artefact"]
