"""What `skel export` writes into an MCAP file and mcapsource.py reads back: the names
both sides must agree on, kept here so neither imports the other (as the `mcap`
package keeps its well-known encodings in one small module)."""

from __future__ import annotations

METADATA = "skeleton"  # the metadata record: system, run id, generation, source integrity
SOURCE_LOG = "run.lcm"  # the attachment holding the source LCM log, byte for byte
FAULTS_TOPIC = "/faults"
TIMING_PREFIX = "/timing/"  # + <dpu>/<process>: one message per process cycle
