// Procedural textures and shading.
//
// Textures are functions of surface coordinates (uv, metres) and of the point
// in the surface's own frame, so a surface point looks the same from every
// view. Detail finer than about two pixels is faded out using the pixel
// footprint (a cheap prefilter that keeps the images from aliasing).
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "long3r/synth/geometry.hpp"
#include "long3r/synth/texture.hpp"

namespace long3r::synth {

namespace {

inline uint32_t rotl(uint32_t x, int r) { return (x << r) | (x >> (32 - r)); }
inline uint32_t fmix(uint32_t h) {
  h ^= h >> 16;
  h *= 0x85ebca6bu;
  h ^= h >> 13;
  h *= 0xc2b2ae35u;
  h ^= h >> 16;
  return h;
}
inline uint32_t hash4(int32_t x, int32_t y, int32_t z, uint32_t seed) {
  uint32_t h = seed ^ 0x9e3779b9u;
  for (int32_t v : {x, y, z}) {
    uint32_t k = static_cast<uint32_t>(v) * 0xcc9e2d51u;
    k = rotl(k, 15) * 0x1b873593u;
    h = rotl(h ^ k, 13) * 5u + 0xe6546b64u;
  }
  return fmix(h);
}
inline float unit(uint32_t h) { return static_cast<float>(h >> 8) * (1.0f / 16777216.0f); }

inline float fade(float t) { return t * t * t * (t * (t * 6.0f - 15.0f) + 10.0f); }
inline float lerp(float a, float b, float t) { return a + (b - a) * t; }
inline float smoothstep(float e0, float e1, float x) {
  const float t = std::clamp((x - e0) / (e1 - e0), 0.0f, 1.0f);
  return t * t * (3.0f - 2.0f * t);
}

// Value noise in [0, 1).
float noise3(float x, float y, float z, uint32_t seed) {
  const float fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
  const int32_t ix = static_cast<int32_t>(fx), iy = static_cast<int32_t>(fy),
                iz = static_cast<int32_t>(fz);
  const float tx = fade(x - fx), ty = fade(y - fy), tz = fade(z - fz);
  float c[8];
  for (int i = 0; i < 8; ++i)
    c[i] = unit(hash4(ix + (i & 1), iy + ((i >> 1) & 1), iz + (i >> 2), seed));
  const float x00 = lerp(c[0], c[1], tx), x10 = lerp(c[2], c[3], tx);
  const float x01 = lerp(c[4], c[5], tx), x11 = lerp(c[6], c[7], tx);
  return lerp(lerp(x00, x10, ty), lerp(x01, x11, ty), tz);
}

// Fractal noise, zero mean, roughly in [-0.5, 0.5]. Octaves with a wavelength
// below ~2 footprints are faded out.
float fbm(const Eigen::Vector3f& p, float wavelength, float footprint, uint32_t seed,
          int octaves = 6) {
  float sum = 0.0f, amp = 0.5f, freq = 1.0f / wavelength, norm = 0.0f;
  for (int o = 0; o < octaves; ++o) {
    const float lambda = 1.0f / freq;
    const float keep = std::clamp((lambda - 2.0f * footprint) / (2.0f * footprint), 0.0f, 1.0f);
    norm += amp;
    if (keep > 0.0f) {
      const float off = 17.0f * o;
      sum += amp * keep *
             (noise3(p.x() * freq + off, p.y() * freq - off, p.z() * freq + 0.5f * off,
                     seed + 101u * o) -
              0.5f);
    }
    amp *= 0.5f;
    freq *= 2.0f;
  }
  return sum / norm;
}

// Anti-aliased square wave of period 2 * half_period in [-1, 1].
inline float square_wave(float x, float half_period, float footprint) {
  const float s = std::sin(static_cast<float>(M_PI) * x / half_period);
  const float slope = half_period / (static_cast<float>(M_PI) * std::max(footprint, 1e-6f));
  return std::clamp(s * slope, -1.0f, 1.0f);
}

// Per-cell colour jitter around `base`.
inline Eigen::Vector3f cell_colour(const Eigen::Vector3f& base, float variation, uint32_t h) {
  const float v = (unit(h) - 0.5f) * 2.0f * variation;
  const float hue_r = (unit(fmix(h + 1u)) - 0.5f) * variation;
  const float hue_b = (unit(fmix(h + 2u)) - 0.5f) * variation;
  return (base * (1.0f + v) + Eigen::Vector3f(hue_r, 0.0f, hue_b)).cwiseMax(0.0f).cwiseMin(1.0f);
}

// Grid cells with grout lines between them. Returns the colour; `row_shift`
// offsets every other row by half a cell (bricks).
Eigen::Vector3f cells(const Material& m, float u, float v, float cw, float ch, bool row_shift,
                      float footprint) {
  const float row = std::floor(v / ch);
  if (row_shift && static_cast<int32_t>(row) % 2 != 0) u += 0.5f * cw;
  const float col = std::floor(u / cw);
  const float fu = u - col * cw, fv = v - row * ch;
  const float edge = std::min({fu, cw - fu, fv, ch - fv});
  const float grout = 0.05f * std::min(cw, ch);
  const float in_cell = smoothstep(grout - footprint, grout + footprint, edge);
  const uint32_t h = hash4(static_cast<int32_t>(col), static_cast<int32_t>(row), 7, m.seed);
  const Eigen::Vector3f c = cell_colour(m.base, m.cell_variation, h);
  return m.accent + (c - m.accent) * in_cell;
}

Eigen::Vector3f pattern_colour(const Material& m, const Eigen::Vector2f& uv,
                               const Eigen::Vector3f& local, float footprint) {
  const float ca = std::cos(m.pattern_angle), sa = std::sin(m.pattern_angle);
  const float u = ca * uv.x() + sa * uv.y();
  const float v = -sa * uv.x() + ca * uv.y();
  const float s = m.pattern_scale;
  // Patterns finer than the footprint fade to the mean colour.
  const float detail = std::clamp((s - 3.0f * footprint) / (3.0f * footprint), 0.0f, 1.0f);
  const Eigen::Vector3f mean = 0.5f * (m.base + m.accent);
  Eigen::Vector3f c = mean;
  switch (m.pattern) {
    case Pattern::kNoise:
      return m.base;
    case Pattern::kTiles:
      c = cells(m, u, v, s, s, false, footprint);
      break;
    case Pattern::kBricks:
      c = cells(m, u, v, s, 0.45f * s, true, footprint);
      break;
    case Pattern::kChecker: {
      const float w = square_wave(u, s, footprint) * square_wave(v, s, footprint);
      const uint32_t h = hash4(static_cast<int32_t>(std::floor(u / s)),
                               static_cast<int32_t>(std::floor(v / s)), 3, m.seed);
      const Eigen::Vector3f a = cell_colour(m.base, m.cell_variation, h);
      c = m.accent + (a - m.accent) * (0.5f + 0.5f * w);
      break;
    }
    case Pattern::kStripes: {
      const float w = square_wave(u, 0.5f * s, footprint);
      const uint32_t h = hash4(static_cast<int32_t>(std::floor(u / s)), 0, 5, m.seed);
      const Eigen::Vector3f a = cell_colour(m.base, m.cell_variation, h);
      c = m.accent + (a - m.accent) * (0.5f + 0.5f * w);
      break;
    }
    case Pattern::kDots: {
      const float cu = std::floor(u / s), cv = std::floor(v / s);
      const uint32_t h = hash4(static_cast<int32_t>(cu), static_cast<int32_t>(cv), 11, m.seed);
      const float jx = (unit(h) - 0.5f) * 0.3f, jy = (unit(fmix(h ^ 0x55u)) - 0.5f) * 0.3f;
      const float radius = (0.2f + 0.15f * unit(fmix(h ^ 0xaau))) * s;
      const float du = u - (cu + 0.5f + jx) * s, dv = v - (cv + 0.5f + jy) * s;
      const float dist = std::sqrt(du * du + dv * dv);
      const float in_dot = 1.0f - smoothstep(radius - footprint, radius + footprint, dist);
      const Eigen::Vector3f dot(0.15f + 0.85f * unit(fmix(h + 11u)),
                                0.15f + 0.85f * unit(fmix(h + 12u)),
                                0.15f + 0.85f * unit(fmix(h + 13u)));
      c = m.base + (dot - m.base) * in_dot;
      break;
    }
    case Pattern::kWood: {
      const float n = fbm(local, 4.0f * s, footprint, m.seed + 7u, 4);
      const float band =
          0.5f + 0.5f * std::sin(2.0f * static_cast<float>(M_PI) * (u / s + 3.0f * n));
      c = m.base + (m.accent - m.base) * (band * band);
      break;
    }
    case Pattern::kMarble: {
      const float n = fbm(local, 2.0f * s, footprint, m.seed + 13u, 5);
      const float vein = std::abs(std::sin(2.0f * static_cast<float>(M_PI) * (u / s + 4.0f * n)));
      const float t = std::pow(1.0f - vein, 6.0f);
      c = m.base + (m.accent - m.base) * t;
      break;
    }
  }
  return mean + (c - mean) * detail;
}

}  // namespace

Eigen::Vector3f shade(const Scene& scene, const Hit& hit, double footprint_d) {
  const Material& m = scene.materials.at(hit.material);
  const float footprint = static_cast<float>(footprint_d);
  const Eigen::Vector3f local = hit.local.cast<float>();
  Eigen::Vector3f albedo = pattern_colour(m, hit.uv.cast<float>(), local, footprint);
  const float n = fbm(local, m.noise_scale, footprint, m.seed);
  albedo *= std::max(0.0f, 1.0f + 2.0f * m.noise_amount * n);
  // Distinct faces of one object differ slightly in tone, like real materials.
  albedo *= 0.88f + 0.24f * unit(hash4(hit.surface_id, 0, 0, m.seed ^ 0x1234u));
  albedo = albedo.cwiseMax(0.0f).cwiseMin(1.0f);

  const Eigen::Vector3d l = scene.light_direction.normalized();
  double light = scene.ambient + scene.directional * std::max(0.0, hit.normal.dot(l));
  const Eigen::Vector3d to_light = scene.point_light - hit.point;
  const double d2 = to_light.squaredNorm();
  if (d2 > 1e-12) {
    const double lam = std::max(0.0, hit.normal.dot(to_light) / std::sqrt(d2));
    light += scene.point_intensity * lam / (1.0 + 0.15 * d2);
  }
  return (albedo * static_cast<float>(light)).cwiseMin(1.0f);
}

}  // namespace long3r::synth
