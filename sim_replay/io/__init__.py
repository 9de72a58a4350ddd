"""Sequence files: the §5.1 JSON (format, reader, writer), real COCO keypoint files, rendered output and
the frames of a sequence's video or image folder."""
