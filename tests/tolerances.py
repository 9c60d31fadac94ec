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

# --- metrics (geometry) ---
#: Open3D closest points are float32: at ~100 mm coordinates a point on the surface
#: comes back within ~1e-5 mm; distances of coincident surfaces stay below this, mm.
CLOSEST_POINT_F32_MM = 1e-4
#: Largest gap between a radius-100 mm subdivision-5 icosphere's faces and its
#: analytic sphere (chord sagitta, measured 0.0285 mm), mm.
ICOSPHERE5_SAGITTA_MM = 0.03
#: 1 - |n . n'| allowed between fine faceted spheres (vertex normal vs face normal
#: around it, adjacent facets ~2 degrees apart: 1 - cos = 6e-4).
NORMAL_CONSISTENCY_FACETED = 1e-3
#: An area fraction estimated from 20K uniform samples (binomial sigma <= 0.0035: ~3 sigma).
AREA_FRACTION_SAMPLED = 0.01
#: Pinned regression scores (deterministic float32 BVH queries; leaves room for
#: another CPU's float rounding), relative.
REGRESSION_RELATIVE = 1e-5
#: Correspondence error of an exact registration: float32 projections through an
#: affine deformation (scales up to 2) of ~100 mm coordinates, mm.
CORRESPONDENCE_EXACT_MM = 1e-4

# --- metrics (photometric) ---
#: LPIPS of the reference image pairs vs the published 0.7219 / 0.1376 (a wrong weight layout moves them by >= 0.01).
LPIPS_REFERENCE = 1e-3
#: float32 LPIPS identities (identical images, swapped arguments, masked vs plain mean of the map).
LPIPS_FLOAT32 = 1e-6
#: Closed-form PSNR (dB) and float64 SSIM identities.
PHOTOMETRIC_EXACT = 1e-9
#: SSIM of our masked reduction vs scikit-image's full map averaged by hand (float32 maps).
SSIM_VS_SKIMAGE = 1e-6
#: PSNR of a mesh rendered against its own render, dB (identical renders give +inf).
SELF_RENDER_PSNR_DB = 60.0

# --- baselines ---
#: NICP on the bumped ellipsoid must cut the scan-to-mesh mean distance at least this much (acceptance).
NICP_MIN_DISTANCE_REDUCTION = 10.0
#: Template vertices the open scan does not cover (the back) stay this close to the full
#: bumped ellipsoid, mm: bump height (4 mm) plus slack; dragging onto the scan's rim is ~30 mm.
NICP_BACK_OF_HEAD_MM = 6.0

# --- report (figures) ---
#: Projection of a framed point set's centre onto the image centre, px (float64 pinhole).
FIGURE_CENTRE_PX = 1e-6
#: A constant per-vertex value interpolated by the renderer (float32 barycentrics).
INTERPOLATED_CONSTANT = 1e-5
