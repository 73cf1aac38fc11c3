"""Answers from a calibrated camera: readings at any setting (readings), the stimulus behind a
reading or an image (invert, images), the setting that reaches a target (plan), and the
cheapest model a scene needs (scene)."""
