"""Low-level keyframe policies."""
