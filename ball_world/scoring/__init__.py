"""How well tracks follow balls: the mathematics of ball_world_score, without ROS or files.

Each module is one piece, pure functions of numbers (docs/scoring.md says what they mean):
`similarity` (distance to similarity, the thresholds), `frames` (a scan's ground truth and
tracks, the don't-care rule, TrackEval's sequence layout), `clear`, `identity`, `hota` and
`detection` (the metrics), `breakdown` (per ball and per track), `stamps` (pairing track
messages with scans), `planar_tf` (2D transforms from /tf), `scenes` (means and confidence
intervals over many scenes). The command line (`tools/score.py`) and its readers feed them.
"""
