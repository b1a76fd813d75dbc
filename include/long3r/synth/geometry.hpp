// The scenes of the procedural generator and ray casting against them
// (synth/geometry.cpp): the room, the furniture, the surfaces' materials and
// ray-scene intersection.
//
// A scene is a closed box room (walls, floor, ceiling) with furniture-like
// boxes, vertical cylinders and spheres, and wall pictures/rugs (thin boxes).
// World W has z up, the room spans [0, size.x] x [0, size.y] x [0, size.z]
// metres.
#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <string>
#include <vector>

namespace long3r::synth {

enum class Pattern { kNoise, kTiles, kBricks, kChecker, kStripes, kDots, kWood, kMarble };

// Surface appearance. Colours are linear RGB in [0, 1].
struct Material {
  Eigen::Vector3f base{0.5f, 0.5f, 0.5f};
  Eigen::Vector3f accent{0.2f, 0.2f, 0.2f};
  Pattern pattern = Pattern::kNoise;
  float pattern_scale = 0.3f;   // metres: tile / brick / stripe period
  float pattern_angle = 0.0f;   // radians, rotation of the pattern in the surface
  float noise_scale = 0.5f;     // metres: wavelength of the coarsest noise octave
  float noise_amount = 0.3f;    // noise contrast
  float cell_variation = 0.2f;  // per-tile/brick/dot colour variation
  uint32_t seed = 0;
};

enum class ShapeType { kBox, kCylinder, kSphere };

// Furniture. Boxes may be rotated about the world z axis (yaw); cylinders
// are vertical.
struct Shape {
  ShapeType type = ShapeType::kBox;
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  Eigen::Vector3d half_size =
      Eigen::Vector3d::Constant(0.5);  // box; cyl (r, r, h/2); sphere (r, r, r)
  double yaw = 0.0;
  int material = 0;
  std::string label;  // "table", "cabinet", "picture", ... (informational)

  // Euclidean distance from p to the solid (0 inside).
  double distance(const Eigen::Vector3d& p) const;
};

struct Scene {
  Eigen::Vector3d room_size{5.0, 4.0, 2.7};
  // Room surfaces: 0 x=0 wall, 1 x=max wall, 2 y=0 wall, 3 y=max wall, 4 floor, 5 ceiling.
  int room_material[6] = {0, 0, 0, 0, 0, 0};
  std::vector<Shape> shapes;
  std::vector<Material> materials;
  Eigen::Vector3d light_direction{0.3, 0.2, 1.0};  // towards the light (normalised on use)
  Eigen::Vector3d point_light{2.5, 2.0, 2.4};
  double ambient = 0.3, directional = 0.4, point_intensity = 0.45;
};

// Ray-scene intersection. `dir` need not be normalised; t is in units of it
// (so with dir = R * (x, y, 1) t is the z-depth). surface_id: room surface
// 0..5, or 16 * (shape index + 1) + face.
struct Hit {
  double t = 0.0;
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();  // unit, facing the ray origin
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();      // surface coordinates in metres
  Eigen::Vector3d local = Eigen::Vector3d::Zero();   // point in the surface's own frame
  int material = 0;
  int surface_id = -1;
};
bool intersect(const Scene& scene, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir,
               Hit* hit);

}  // namespace long3r::synth
