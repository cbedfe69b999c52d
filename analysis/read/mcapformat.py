"""What `skel export` writes into an MCAP file and mcapsource.py reads back: the names
both sides must agree on, kept here so neither imports the other (as the `mcap`
package keeps its well-known encodings in one small module)."""

from __future__ import annotations

from .records import CYCLE_FIELDS

METADATA = "skeleton"  # the metadata record: system, run id, generation, source integrity
RAW_TOPIC = "/lcm/raw"  # LCM events kept as bytes (undecodable, or a repeated timing batch)
FAULTS_TOPIC = "/faults"
TIMING_PREFIX = "/timing/"  # + <dpu>/<process>: one message per process cycle
RECORD_FIELDS = ["process", *CYCLE_FIELDS, "flags"]  # a timing message's record part
INPUT_FIELDS = ["buffer", "seq", "new", "dropped", "received", "sent_ns", "recv_ns"]
