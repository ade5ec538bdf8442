// The drawing rule that the projection (project_cpu.cpp: where a Gaussian's box ends) and the compositor
// (composite_cpu.cpp: which pixels it adds to) must share, as glimpse/render/projection.py's ALPHA_MIN.
#pragma once

namespace glimpse_raster {

constexpr float kAlphaMin = 1.0f / 255.0f;  // projection.py ALPHA_MIN: a pixel takes a Gaussian when alpha >= this

}  // namespace glimpse_raster
