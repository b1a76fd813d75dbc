// The surfaces' appearance (synth/texture.cpp): every surface has a
// procedural texture (multi-octave value noise plus a pattern: tiles, bricks,
// checks, stripes, dots, wood or marble bands, with per-cell colour variation)
// so that images carry features at several scales. Shading is Lambertian (one
// directional and one point light) plus ambient, without shadows, so a
// surface point has the same colour from every view.
#pragma once

#include <Eigen/Core>

#include "long3r/synth/geometry.hpp"

namespace long3r::synth {

// Texture colour (linear RGB) at a hit; footprint = metres per pixel there,
// used to fade out detail finer than a pixel.
Eigen::Vector3f shade(const Scene& scene, const Hit& hit, double footprint);

}  // namespace long3r::synth
