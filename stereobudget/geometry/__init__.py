"""Real camera pairs: calibration files, rectification at the host, depth in metres, point clouds.

The camera side does not change: it sends its raw, unrectified grid.  The host reads the
stereo calibration (:func:`read_calibration`: OpenCV YAML/XML, JSON, Middlebury
``calib.txt``), rectifies I1 and places each sample where it lands in the rectified right
frame (:func:`rectify_stereo`, :func:`rectify_left`, :func:`rectify_samples`), decodes
there, and turns the disparity into metric depth for the left image as given
(:func:`depth_map`, ``Z = f B / (d + doffs)``) and a coloured point cloud
(:func:`point_cloud`, :func:`write_ply`).
"""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_calibration': ['UNITS', 'DISTORTION_LENGTHS', 'StereoCalibration', 'read_calibration', 'check_image_size'],
    '_rectify': ['Rectification', 'rectify_stereo', 'rectification_for', 'rectify_left', 'PlacedSamples', 'SampleLattice',
                 'map_sample_positions', 'rectify_samples', 'raw_left_disparity', 'depth_map', 'raw_points',
                 'point_cloud', 'raw_right_positions'],
    '_output': ['DEPTH_EXTENSIONS', 'PNG_DEPTH_MAX_M', 'encode_depth', 'write_depth', 'read_depth', 'encode_ply',
                'write_ply'],
    '_synthetic': ['UnrectifiedPair', 'unrectify_pair', 'write_calibration'],
    '_selfrect': ['MIN_MATCHES', 'MAX_RESIDUAL', 'CHECK_EVERY', 'SelfRectificationReport', 'SelfRectifiedStream',
                  'match_lattice', 'guided_matches', 'frame_residual', 'self_rectification'],
})
