"""Numerical tolerances shared by the tests, named once (gpytoolbox/trimesh style)."""

#: float64 geometric identities (projection round trips, transforms), mm or px.
EXACT_F64 = 1e-9
#: Rays vs points, undistortion iterations (OpenCV's iterative solver), px.
UNDISTORT_PX = 1e-6
#: Error left after distorting then undistorting a smooth image, as a fraction of
#: the change distortion made (bilinear resampling twice).
IMAGE_ROUNDTRIP_RATIO = 0.15
#: The same for images stored as 8-bit PNG (quantisation adds ~1e-3).
IMAGE_ROUNDTRIP_RATIO_8BIT = 0.5
#: PNG texture quantisation, [0, 1] units.
UINT8_STEP = 1.0 / 255.0 + 1e-6
#: Numerical quadrature over the sphere (SH orthonormality), absolute.
SPHERE_QUADRATURE = 2e-3
#: Ground-truth landmarks to scan surface, mm (scan is a 0.5-1 mm triangulation).
LANDMARK_TO_SCAN_MM = 1.0
#: Renderer depth vs Open3D ray casting, median over pixels, mm (issue: <= 1e-3).
DEPTH_VS_RAYCAST_MM = 1e-3
#: Interpolated vertex normals vs Open3D face normals on a fine sphere, median, degrees.
NORMAL_VS_RAYCAST_DEG = 1.0
#: Fraction of pixels whose triangle id may differ from Open3D's (ties on edges).
TRI_ID_MISMATCH = 1e-3
#: Relative error of finite-difference vs autograd vertex gradients.
FD_RELATIVE = 1e-3
