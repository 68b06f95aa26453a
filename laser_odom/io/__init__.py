"""Bag and file input/output; rosbags is imported here, never in core."""  # noqa: A005
