"""SAPIENT (BSI Flex 335 v2.0) sensor-node output: ``SapientSink`` (sink), its TCP session and
tasks (session, tasks), the messages (messages, geometry) and the framing (framing); docs/sapient.md."""
