"""One pose's capture: the pipeline (move, settle, capture, features, segment, fit), the
camera's lock, segmentation and its palette, the skip rules, mask files, the exposure
calibration, and the filing of captures under sequence numbers.
"""
