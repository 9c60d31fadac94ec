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
#: A render (values, vertex gradients) with the faces in another order: the same up to the rounding of the
#: per-vertex sums, relative to the largest value.
FACE_ORDER_RELATIVE = 1e-5

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
#: A scan scored against its own vertices at their true positions with no noise (mm): the PLY's float32 positions
SCAN_AGAINST_ITSELF_MM = 1e-3
#: The mean distance of Gaussian-noisy scan vertices to the true surface against sigma * sqrt(2 / pi) (relative):
#: the surface curves within a noise's reach, and a tiny subject has a few thousand vertices
NOISE_MEAN_DISTANCE_RELATIVE = 0.15
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

# --- lighting estimate (gpja/register/lighting_estimate.py, gpja/metrics/lighting.py) ---
#: SH recovered from exact synthetic samples (float64 normal equations, condition <= ~1e3), relative.
SH_EXACT_RELATIVE = 1e-9
#: SH recovered on a sphere whose constant albedo carries +-5% noise and 20% dark outliers (measured 0.5%), relative.
SH_NOISY_RELATIVE = 0.02

# --- texture fusion (gpja/render/uv_raster.py, gpja/register/texture_fill.py, gpja/register/texture_fusion.py) ---
#: Barycentrics of texel centres just outside a UV triangle's float edge: the rasteriser snaps to 1/256 texel.
UV_RASTER_BARY = 5e-3
#: float32 push-pull of a constant image, and of texels of full weight, [0, 1] units.
FILL_EXACT = 1e-5
#: Push-pull across a 24-texel hole of a unit ramp over 64 texels vs the ramp itself (measured 0.050: the
#: Gaussian pyramid is smooth, not harmonic), [0, 1] units.
FILL_LINEAR_RAMP = 0.065
#: Both copies of a seam after the seam pass, one side observed (measured 5e-4), [0, 1] units.
FILL_SEAM_AGREEMENT = 0.005
#: OpenCV's remap rounds sample positions to 1/32 pixel (INTER_TAB_SIZE), px.
REMAP_POSITION_PX = 1.0 / 32.0
#: Fused albedo of a linear texture on planes (one view affine, one perspective; remap rounding; measured
#: 4e-6), max, [0, 1] units.
FUSION_FLAT_ALBEDO = 1e-3
#: Fused albedo of a smooth texture on a 96 px sphere under directional light, mean over observed texels
#: (measured 0.002).
FUSION_SPHERE_ALBEDO = 0.005
#: The sphere rendered with its fused texture vs the references (measured 51.3 dB), dB.
FUSION_RENDER_PSNR_DB = 45.0
#: The fused sphere texture (64 texels, a colour field of 250 mm period) at both UV copies of every seam vertex,
#: mean (measured 0.0086; the baked truth itself: 0.029), [0, 1] units.
FUSION_SEAM_AGREEMENT = 0.015
#: Template lighting estimated from a spotted sphere (scan normals, 96 px views) vs the truth, relative (DC-matched;
#: measured 0.015: the estimator's ridge pulls the truth's band-2 term towards 0).
TEMPLATE_LIGHTING_RELATIVE = 0.05
#: The fused albedo of that sphere vs the truth after one per-channel scale, mean (measured 0.0044), [0, 1] units.
TEMPLATE_ALBEDO_UP_TO_SCALE = 0.01
#: Mean change of an (already exact) fused sphere texture by 30 refinement steps of lr 0.01 (measured 0.0035),
#: [0, 1] units.
TEMPLATE_REFINE_CHANGE = 0.01

# --- colour gain (gpja.register.gain) ---
#: A per-channel gain measured on references that are the start's own render times that gain (the median of exact
#: ratios; measured 9e-8), relative.
GAIN_EXACT = 1e-5
#: The same with the references rendered from the bust with its jaw opened 3 degrees (the mouth's pixels off;
#: measured 0.0007), relative.
GAIN_MISALIGNED = 0.005

# --- registration, end to end ---
#: Median error (mm) of the lower lip of a closed mouth registered from the mouth-open template at CI size
#: (tests/test_open_to_closed.py): the default measured 1.4-2.6 mm on seeds 0-2, the paper's schedule 27-38 mm;
#: two 256^2 pixels (~2 mm each), far below the open mouth's ~20 mm.
LOWER_LIP_CLOSED_MM = 4.0

# --- metrics (the artist mesh's turned faces) ---
#: Newton's inverse of a smooth map of space (the synthetic expressions'), mm: it reaches ~1e-12.
MAP_INVERSE_MM = 1e-8
#: Central-difference Jacobian of a map of space (step 1e-4 mm) against the exact one, relative.
MAP_JACOBIAN_RELATIVE = 1e-7
