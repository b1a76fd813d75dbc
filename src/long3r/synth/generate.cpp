// Scene and camera-path generation.
//
// Order: room -> camera path (inside the room, `clearance` from the walls) ->
// furniture, each piece rejected if it comes within `clearance` of any camera
// position or overlaps earlier pieces. The camera therefore never clips an
// object, whatever the path.
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "long3r/synth/generate.hpp"
#include "long3r/synth/geometry.hpp"

namespace long3r::synth {

namespace {

constexpr double kPi = M_PI;
inline double deg2rad(double d) { return d * kPi / 180.0; }

// ---------------------------------------------------------------- materials

Eigen::Vector3f random_colour(Rng& rng, float sat_lo, float sat_hi, float val_lo, float val_hi) {
  // HSV -> RGB with explicit formulas (portable).
  const double h = rng.uniform(0.0, 6.0);
  const double s = rng.uniform(sat_lo, sat_hi);
  const double v = rng.uniform(val_lo, val_hi);
  const int i = static_cast<int>(std::floor(h)) % 6;
  const double f = h - std::floor(h);
  const double p = v * (1 - s), q = v * (1 - s * f), t = v * (1 - s * (1 - f));
  double r = v, g = t, b = p;
  switch (i) {
    case 0:
      r = v;
      g = t;
      b = p;
      break;
    case 1:
      r = q;
      g = v;
      b = p;
      break;
    case 2:
      r = p;
      g = v;
      b = t;
      break;
    case 3:
      r = p;
      g = q;
      b = v;
      break;
    case 4:
      r = t;
      g = p;
      b = v;
      break;
    default:
      r = v;
      g = p;
      b = q;
      break;
  }
  return Eigen::Vector3f(static_cast<float>(r), static_cast<float>(g), static_cast<float>(b));
}

Material random_material(Rng& rng, const std::vector<Pattern>& allowed, float scale_lo,
                         float scale_hi, bool bright) {
  Material m;
  m.pattern = allowed[rng.uniform_int(0, static_cast<int>(allowed.size()) - 1)];
  m.base = bright ? random_colour(rng, 0.3f, 0.9f, 0.5f, 0.95f)
                  : random_colour(rng, 0.05f, 0.5f, 0.35f, 0.85f);
  m.accent = random_colour(rng, 0.1f, 0.8f, 0.1f, 0.9f);
  m.pattern_scale = static_cast<float>(rng.uniform(scale_lo, scale_hi));
  m.pattern_angle = rng.bernoulli(0.6) ? 0.0f : static_cast<float>(rng.uniform(0.0, kPi));
  m.noise_scale = static_cast<float>(rng.uniform(0.25, 1.2));
  m.noise_amount = static_cast<float>(rng.uniform(0.25, 0.55));
  m.cell_variation = static_cast<float>(rng.uniform(0.1, 0.35));
  m.seed = static_cast<uint32_t>(rng.next_u64() >> 32);
  return m;
}

int add_material(Scene& scene, const Material& m) {
  scene.materials.push_back(m);
  return static_cast<int>(scene.materials.size()) - 1;
}

// ---------------------------------------------------------------- camera

// Camera pose from position and viewing angles. yaw about world z (0 = +x),
// pitch up positive, roll about the viewing direction.
Eigen::Isometry3d camera_pose(const Eigen::Vector3d& position, double yaw, double pitch,
                              double roll) {
  const Eigen::Vector3d f(std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw),
                          std::sin(pitch));
  const Eigen::Vector3d right0 = f.cross(Eigen::Vector3d::UnitZ()).normalized();
  const Eigen::Vector3d down0 = f.cross(right0);
  const Eigen::Vector3d right = std::cos(roll) * right0 + std::sin(roll) * down0;
  const Eigen::Vector3d down = -std::sin(roll) * right0 + std::cos(roll) * down0;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear().col(0) = right;
  T.linear().col(1) = down;
  T.linear().col(2) = f;
  T.translation() = position;
  return T;
}

double wrap_angle(double a) {
  while (a > kPi) a -= 2 * kPi;
  while (a < -kPi) a += 2 * kPi;
  return a;
}

// Limits the per-frame change of an angle sequence (unwrapped on the fly).
void rate_limit(std::vector<double>* angles, double max_step) {
  for (size_t i = 1; i < angles->size(); ++i) {
    const double prev = (*angles)[i - 1];
    const double step = wrap_angle((*angles)[i] - prev);
    (*angles)[i] = prev + std::clamp(step, -max_step, max_step);
  }
}

struct Wobble {  // slow smooth oscillation: sum of two sinusoids
  double a1, p1, w1, a2, p2, w2;
  double operator()(double x) const {
    return a1 * std::sin(w1 * x + p1) + a2 * std::sin(w2 * x + p2);
  }
};
Wobble random_wobble(Rng& rng, double amplitude, double period_lo, double period_hi) {
  Wobble w;
  w.a1 = amplitude * rng.uniform(0.5, 0.7);
  w.a2 = amplitude - w.a1;
  w.p1 = rng.uniform(0.0, 2 * kPi);
  w.p2 = rng.uniform(0.0, 2 * kPi);
  w.w1 = 2 * kPi / rng.uniform(period_lo, period_hi);
  w.w2 = 2 * kPi / rng.uniform(0.4 * period_lo, 0.6 * period_hi);
  return w;
}

struct PathResult {
  std::vector<Eigen::Isometry3d> poses;
  Eigen::Vector3d focus = Eigen::Vector3d::Constant(-1.0);  // orbit centre, when used
  double focus_radius = 0.0;                                // free radius around it
};

// Closed Catmull-Rom loop through points around the room centre, walked at
// constant speed (arc-length parametrised, wrapping around).
PathResult walk_path(Rng& rng, const Eigen::Vector3d& room, const TrajectoryConfig& tc, double h_lo,
                     double h_hi) {
  const double margin = tc.clearance + 0.05;
  const Eigen::Vector2d centre(room.x() / 2, room.y() / 2);
  const double ax = room.x() / 2 - margin, ay = room.y() / 2 - margin;
  const int k = rng.uniform_int(5, 8);
  std::vector<double> radius(k), angle(k);
  const double a0 = rng.uniform(0.0, 2 * kPi);
  for (int i = 0; i < k; ++i) {
    angle[i] = a0 + 2 * kPi * (i + rng.uniform(-0.25, 0.25)) / k;
    radius[i] = rng.uniform(0.35, 0.95);
  }
  std::vector<Eigen::Vector2d> dense;
  for (int attempt = 0;; ++attempt) {
    std::vector<Eigen::Vector2d> pts(k);
    for (int i = 0; i < k; ++i) {
      pts[i] = centre + Eigen::Vector2d(radius[i] * ax * std::cos(angle[i]),
                                        radius[i] * ay * std::sin(angle[i]));
    }
    dense.clear();
    const int per_segment = 200;
    bool inside = true;
    for (int i = 0; i < k; ++i) {
      const Eigen::Vector2d& p0 = pts[(i + k - 1) % k];
      const Eigen::Vector2d& p1 = pts[i];
      const Eigen::Vector2d& p2 = pts[(i + 1) % k];
      const Eigen::Vector2d& p3 = pts[(i + 2) % k];
      for (int j = 0; j < per_segment; ++j) {
        const double t = static_cast<double>(j) / per_segment, t2 = t * t, t3 = t2 * t;
        const Eigen::Vector2d p =
            0.5 * ((2 * p1) + (-p0 + p2) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t2 +
                   (-p0 + 3 * p1 - 3 * p2 + p3) * t3);
        if (std::abs(p.x() - centre.x()) > ax || std::abs(p.y() - centre.y()) > ay) inside = false;
        dense.push_back(p);
      }
    }
    if (inside) break;
    if (attempt > 50) throw std::runtime_error("walk_path: cannot keep the path inside the room");
    for (double& r : radius) r *= 0.93;  // spline overshoot: pull the loop in
  }
  // Arc length table over the closed polyline.
  const size_t n = dense.size();
  std::vector<double> arc(n + 1, 0.0);
  for (size_t i = 0; i < n; ++i) arc[i + 1] = arc[i] + (dense[(i + 1) % n] - dense[i]).norm();
  const double length = arc[n];
  auto at = [&](double s) -> Eigen::Vector2d {
    s = std::fmod(s, length);
    if (s < 0) s += length;
    const size_t i = std::upper_bound(arc.begin(), arc.end(), s) - arc.begin() - 1;
    const double seg = arc[i + 1] - arc[i];
    const double f = seg > 0 ? (s - arc[i]) / seg : 0.0;
    return dense[i] + f * (dense[(i + 1) % n] - dense[i]);
  };

  const Wobble yaw_w = random_wobble(rng, deg2rad(rng.uniform(15.0, 35.0)), 3.0, 6.0);
  const Wobble pitch_w = random_wobble(rng, deg2rad(6.0), 2.0, 5.0);
  const Wobble roll_w = random_wobble(rng, deg2rad(tc.roll_deg), 2.0, 4.0);
  const Wobble height_w = random_wobble(rng, 0.5 * (h_hi - h_lo), 4.0, 8.0);
  const double s0 = rng.uniform(0.0, length);
  const double direction = rng.bernoulli(0.5) ? 1.0 : -1.0;
  const double look = 0.3;  // tangent from +-0.3 m of arc: smooth heading

  std::vector<double> yaw(tc.frames);
  std::vector<Eigen::Vector2d> xy(tc.frames);
  for (int i = 0; i < tc.frames; ++i) {
    const double s = s0 + direction * tc.speed * i;
    xy[i] = at(s);
    const Eigen::Vector2d tangent = direction * (at(s + look) - at(s - look));
    yaw[i] = std::atan2(tangent.y(), tangent.x()) + yaw_w(s);
  }
  rate_limit(&yaw, deg2rad(tc.max_yaw_rate_deg));
  PathResult out;
  const double h_mid = 0.5 * (h_lo + h_hi);
  for (int i = 0; i < tc.frames; ++i) {
    const double s = tc.speed * i;
    const Eigen::Vector3d pos(xy[i].x(), xy[i].y(), h_mid + height_w(s));
    out.poses.push_back(camera_pose(pos, yaw[i], deg2rad(tc.pitch_deg) + pitch_w(s), roll_w(s)));
  }
  return out;
}

// A wheeled base patrolling a rounded rectangle at constant speed, heading
// along it: straight runs and quarter circles whose radius keeps the turn
// within max_yaw_rate_deg per frame, as a differential drive drives. The
// rectangle keeps the base `clearance` plus the mount's horizontal offset
// from the walls, so the camera keeps `clearance` too.
PathResult robot_path(Rng& rng, const Eigen::Vector3d& room, const TrajectoryConfig& tc,
                      std::vector<Eigen::Isometry3d>* base_poses) {
  const CameraMount& m = tc.mount;
  const double margin = tc.clearance + 0.05 + std::hypot(m.x, m.y);
  const double ax = room.x() / 2 - margin, ay = room.y() / 2 - margin;
  const double r_min = 1.05 * tc.speed / deg2rad(tc.max_yaw_rate_deg);
  if (std::min(ax, ay) < r_min) {
    throw std::invalid_argument("generate_sequence: room too small for the robot to turn (radius " +
                                std::to_string(r_min) + " m)");
  }
  const double hx = ax * rng.uniform(std::max(0.6, r_min / ax), 1.0);
  const double hy = ay * rng.uniform(std::max(0.6, r_min / ay), 1.0);
  const Eigen::Vector2d centre(room.x() / 2 + rng.uniform(hx - ax, ax - hx),
                               room.y() / 2 + rng.uniform(hy - ay, ay - hy));
  const double r = std::max(r_min, std::min(hx, hy) * rng.uniform(0.5, 1.0));
  // Four sides, counter-clockwise from the middle of the bottom one: a straight
  // run, then a quarter circle.
  const double straight[4] = {2 * (hx - r), 2 * (hy - r), 2 * (hx - r), 2 * (hy - r)};
  const double arc = 0.5 * kPi * r;
  const double length = 2 * (straight[0] + straight[1]) + 4 * arc;
  const Eigen::Vector2d start = centre + Eigen::Vector2d(0.0, -hy);
  auto at = [&](double s, Eigen::Vector2d* p, double* heading) {
    s = std::fmod(s, length);
    if (s < 0) s += length;
    s += 0.5 * straight[0];  // start mid-side
    Eigen::Vector2d q = start - Eigen::Vector2d(0.5 * straight[0], 0.0);
    for (int side = 0;; side = (side + 1) % 4) {
      const double h = side * 0.5 * kPi;
      const Eigen::Vector2d dir(std::cos(h), std::sin(h)), left(-dir.y(), dir.x());
      if (s <= straight[side]) {
        *p = q + s * dir;
        *heading = h;
        return;
      }
      s -= straight[side];
      q += straight[side] * dir;
      const double a = std::min(s, arc) / r;  // angle turned on this corner
      const Eigen::Vector2d pivot = q + r * left;
      if (s <= arc) {
        *p = pivot - r * (std::cos(a) * left - std::sin(a) * dir);
        *heading = h + a;
        return;
      }
      s -= arc;
      q = pivot + r * dir;
    }
  };
  const double s0 = rng.uniform(0.0, length);
  const double direction = rng.bernoulli(0.5) ? 1.0 : -1.0;
  const Eigen::Isometry3d T_B_C = m.base_to_optical();
  PathResult out;
  base_poses->clear();
  for (int i = 0; i < tc.frames; ++i) {
    Eigen::Vector2d p;
    double heading = 0.0;
    at(s0 + direction * tc.speed * i, &p, &heading);
    if (direction < 0) heading += kPi;  // clockwise: driving the other way
    Eigen::Isometry3d T_W_B = Eigen::Isometry3d::Identity();
    T_W_B.linear() =
        Eigen::AngleAxisd(wrap_angle(heading), Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T_W_B.translation() = Eigen::Vector3d(p.x(), p.y(), 0.0);
    base_poses->push_back(T_W_B);
    out.poses.push_back(T_W_B * T_B_C);
  }
  return out;
}

// Circle (slightly varying radius) around the room centre, looking at it.
PathResult orbit_path(Rng& rng, const Eigen::Vector3d& room, const TrajectoryConfig& tc,
                      double h_lo, double h_hi) {
  const double margin = tc.clearance + 0.05;
  const Eigen::Vector2d centre(room.x() / 2, room.y() / 2);
  const double r_max = std::min(room.x(), room.y()) / 2 - margin;
  const double r = r_max * rng.uniform(0.8, 1.0);
  const double theta0 = rng.uniform(0.0, 2 * kPi);
  const double direction = rng.bernoulli(0.5) ? 1.0 : -1.0;
  const double r_var = 0.08;
  const double phase = rng.uniform(0.0, 2 * kPi);
  const Wobble height_w = random_wobble(rng, 0.5 * (h_hi - h_lo), 4.0, 8.0);
  const Wobble look_w = random_wobble(rng, 0.25, 2.0, 4.0);
  const Wobble roll_w = random_wobble(rng, deg2rad(tc.roll_deg), 2.0, 4.0);
  const double target_z = rng.uniform(0.6, 1.0);
  PathResult out;
  out.focus = Eigen::Vector3d(centre.x(), centre.y(), target_z);
  out.focus_radius = r * (1.0 - 2 * r_var);
  for (int i = 0; i < tc.frames; ++i) {
    const double s = tc.speed * i;
    const double theta = theta0 + direction * s / r;
    const double ri = r * (1.0 - r_var + r_var * std::sin(2 * theta + phase));
    const Eigen::Vector3d pos(centre.x() + ri * std::cos(theta), centre.y() + ri * std::sin(theta),
                              0.5 * (h_lo + h_hi) + height_w(s));
    const Eigen::Vector3d target(centre.x() + look_w(s), centre.y() + look_w(s + 7.0), target_z);
    const Eigen::Vector3d d = target - pos;
    const double yaw = std::atan2(d.y(), d.x());
    const double pitch = std::atan2(d.z(), std::hypot(d.x(), d.y()));
    out.poses.push_back(camera_pose(pos, yaw, pitch, roll_w(s)));
  }
  return out;
}

// Out-and-back translation along a line while the view pans left and right:
// every place and view direction is visited again.
PathResult pan_path(Rng& rng, const Eigen::Vector3d& room, const TrajectoryConfig& tc, double h_lo,
                    double h_hi) {
  const double margin = tc.clearance + 0.05;
  const double lo_x = margin, hi_x = room.x() - margin;
  const double lo_y = margin, hi_y = room.y() - margin;
  const Eigen::Vector2d p0(rng.uniform(lo_x + 0.3 * (hi_x - lo_x), hi_x - 0.3 * (hi_x - lo_x)),
                           rng.uniform(lo_y + 0.3 * (hi_y - lo_y), hi_y - 0.3 * (hi_y - lo_y)));
  const double dir_angle = rng.uniform(0.0, 2 * kPi);
  const Eigen::Vector2d dir(std::cos(dir_angle), std::sin(dir_angle));
  // Longest step along dir that stays inside.
  double reach = 1.5;
  for (int k = 0; k < 2; ++k) {
    if (std::abs(dir(k)) < 1e-9) continue;
    const double lo = k == 0 ? lo_x : lo_y, hi = k == 0 ? hi_x : hi_y;
    reach = std::min(reach, ((dir(k) > 0 ? hi : lo) - p0(k)) / dir(k));
  }
  const double amplitude = std::max(0.0, reach);
  const double t_period = std::max(20.0, kPi * amplitude / tc.speed);  // peak speed = tc.speed
  const double pan = deg2rad(rng.uniform(55.0, 80.0));
  const double p_period = std::max(20.0, 2 * kPi * pan / deg2rad(tc.max_yaw_rate_deg));
  const Eigen::Vector2d centre(room.x() / 2, room.y() / 2);
  const Eigen::Vector2d to_c = centre - p0;
  const double yaw0 = to_c.norm() > 0.2 ? std::atan2(to_c.y(), to_c.x()) : dir_angle + kPi / 2;
  const Wobble pitch_w = random_wobble(rng, deg2rad(5.0), 100.0, 200.0);
  const Wobble roll_w = random_wobble(rng, deg2rad(tc.roll_deg), 80.0, 160.0);
  const Wobble height_w = random_wobble(rng, 0.25 * (h_hi - h_lo), 150.0, 300.0);
  PathResult out;
  for (int i = 0; i < tc.frames; ++i) {
    const double a = amplitude * 0.5 * (1.0 - std::cos(2 * kPi * i / t_period));
    const Eigen::Vector3d pos(p0.x() + a * dir.x(), p0.y() + a * dir.y(),
                              0.5 * (h_lo + h_hi) + height_w(i));
    const double yaw = yaw0 + pan * std::sin(2 * kPi * i / p_period);
    out.poses.push_back(camera_pose(pos, yaw, deg2rad(tc.pitch_deg) + pitch_w(i), roll_w(i)));
  }
  return out;
}

// ---------------------------------------------------------------- furniture

struct Placer {
  Scene* scene;
  Rng* rng;
  const std::vector<Eigen::Vector3d>* cameras;
  double clearance;
  std::vector<Eigen::Vector4d> footprints;  // floor AABBs (x0, y0, x1, y1) of standing pieces

  bool clear_of_cameras(const Shape& s) const {
    for (const auto& c : *cameras) {
      if (s.distance(c) < clearance) return false;
    }
    return true;
  }
  static Eigen::Vector4d aabb(const Shape& s) {
    double ex = s.half_size.x(), ey = s.half_size.y();
    if (s.type == ShapeType::kBox) {
      const double c = std::abs(std::cos(s.yaw)), sn = std::abs(std::sin(s.yaw));
      ex = c * s.half_size.x() + sn * s.half_size.y();
      ey = sn * s.half_size.x() + c * s.half_size.y();
    }
    return {s.center.x() - ex, s.center.y() - ey, s.center.x() + ex, s.center.y() + ey};
  }
  bool inside_room(const Eigen::Vector4d& b) const {
    const Eigen::Vector3d& r = scene->room_size;
    return b(0) >= 0.0 && b(1) >= 0.0 && b(2) <= r.x() && b(3) <= r.y();
  }
  bool overlaps(const Eigen::Vector4d& b, double gap) const {
    for (const auto& f : footprints) {
      if (b(0) < f(2) + gap && f(0) < b(2) + gap && b(1) < f(3) + gap && f(1) < b(3) + gap) {
        return true;
      }
    }
    return false;
  }
  // Standing piece: inside the room, apart from others, clear of cameras.
  bool try_stand(const Shape& s) {
    const Eigen::Vector4d b = aabb(s);
    if (!inside_room(b) || overlaps(b, 0.05) || !clear_of_cameras(s)) return false;
    footprints.push_back(b);
    scene->shapes.push_back(s);
    return true;
  }
  // Piece resting on another (no footprint bookkeeping).
  bool try_on_top(const Shape& s) {
    if (!clear_of_cameras(s) || s.center.z() + s.half_size.z() > scene->room_size.z() - 0.05) {
      return false;
    }
    scene->shapes.push_back(s);
    return true;
  }
};

const std::vector<Pattern> kAnyPattern = {Pattern::kNoise,   Pattern::kTiles,   Pattern::kBricks,
                                          Pattern::kChecker, Pattern::kStripes, Pattern::kDots,
                                          Pattern::kWood,    Pattern::kMarble};
const std::vector<Pattern> kSpherePattern = {Pattern::kNoise, Pattern::kStripes, Pattern::kMarble};

Shape random_standing(Rng& rng, const Scene& scene, int material) {
  const Eigen::Vector3d& room = scene.room_size;
  Shape s;
  s.material = material;
  const double kind = rng.uniform();
  if (kind < 0.22) {  // table
    s.type = ShapeType::kBox;
    s.label = "table";
    s.half_size =
        Eigen::Vector3d(rng.uniform(0.4, 0.8), rng.uniform(0.3, 0.5), 0.5 * rng.uniform(0.7, 0.8));
  } else if (kind < 0.42) {  // cabinet / shelf
    s.type = ShapeType::kBox;
    s.label = "cabinet";
    s.half_size = Eigen::Vector3d(rng.uniform(0.2, 0.6), rng.uniform(0.15, 0.3),
                                  0.5 * std::min(rng.uniform(0.8, 2.1), room.z() - 0.1));
  } else if (kind < 0.57) {  // crate
    s.type = ShapeType::kBox;
    s.label = "crate";
    const double h = rng.uniform(0.15, 0.3);
    s.half_size = Eigen::Vector3d(h, h * rng.uniform(0.8, 1.2), h * rng.uniform(0.8, 1.2));
  } else if (kind < 0.72) {  // barrel / stool
    s.type = ShapeType::kCylinder;
    s.label = "barrel";
    const double r = rng.uniform(0.15, 0.35);
    s.half_size = Eigen::Vector3d(r, r, 0.5 * rng.uniform(0.4, 1.1));
  } else if (kind < 0.80) {  // pillar, floor to ceiling
    s.type = ShapeType::kCylinder;
    s.label = "pillar";
    const double r = rng.uniform(0.15, 0.3);
    s.half_size = Eigen::Vector3d(r, r, 0.5 * room.z());
  } else {  // ball
    s.type = ShapeType::kSphere;
    s.label = "ball";
    const double r = rng.uniform(0.15, 0.4);
    s.half_size = Eigen::Vector3d(r, r, r);
  }
  s.yaw = (s.type == ShapeType::kBox && rng.bernoulli(0.6)) ? rng.uniform(0.0, kPi) : 0.0;
  const double ex = std::max(s.half_size.x(), s.half_size.y());
  if (s.label == "cabinet" && rng.bernoulli(0.7)) {
    // Against a wall, back to it.
    const int wall = rng.uniform_int(0, 3);
    s.yaw = (wall < 2) ? kPi / 2 : 0.0;
    const double d = s.half_size.y() + 0.01;
    const double along_lo = ex + 0.05;
    if (wall < 2) {
      s.center.x() = wall == 0 ? d : room.x() - d;
      s.center.y() = rng.uniform(along_lo, room.y() - along_lo);
    } else {
      s.center.y() = wall == 2 ? d : room.y() - d;
      s.center.x() = rng.uniform(along_lo, room.x() - along_lo);
    }
  } else {
    s.center.x() = rng.uniform(0.05 + ex, room.x() - 0.05 - ex);
    s.center.y() = rng.uniform(0.05 + ex, room.y() - 0.05 - ex);
  }
  s.center.z() = s.half_size.z();  // standing on the floor
  return s;
}

}  // namespace

// ------------------------------------------------------------------- Rng

double Rng::uniform() { return static_cast<double>(next_u64() >> 11) * (1.0 / 9007199254740992.0); }
double Rng::uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
int Rng::uniform_int(int lo, int hi) {
  if (hi < lo) throw std::invalid_argument("Rng::uniform_int: hi < lo");
  const uint64_t range = static_cast<uint64_t>(hi) - static_cast<uint64_t>(lo) + 1;
  return lo + static_cast<int>(next_u64() % range);
}
double Rng::normal(double mean, double stddev) {
  const double u1 = 1.0 - uniform();  // (0, 1]
  const double u2 = uniform();
  return mean + stddev * std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
}

TrajectoryType trajectory_type_from_string(const std::string& name) {
  if (name == "walk") return TrajectoryType::kWalk;
  if (name == "orbit") return TrajectoryType::kOrbit;
  if (name == "pan" || name == "pan_return") return TrajectoryType::kPanReturn;
  if (name == "robot") return TrajectoryType::kRobot;
  throw std::invalid_argument("unknown trajectory type '" + name + "' (walk|orbit|pan|robot)");
}

const char* to_string(TrajectoryType type) {
  switch (type) {
    case TrajectoryType::kWalk:
      return "walk";
    case TrajectoryType::kOrbit:
      return "orbit";
    case TrajectoryType::kPanReturn:
      return "pan";
    case TrajectoryType::kRobot:
      return "robot";
  }
  return "?";
}

uint64_t derived_seed(uint64_t seed, uint64_t stream) {
  // splitmix64 (Steele et al.) over both words: well-mixed, portable.
  auto mix = [](uint64_t z) {
    z += 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  };
  return mix(mix(seed) ^ stream);
}

Eigen::Isometry3d camera_link_to_optical() {
  // Columns: the optical x (right), y (down), z (forward) in camera_link.
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() << 0, 0, 1, -1, 0, 0, 0, -1, 0;
  return T;
}

Eigen::Isometry3d CameraMount::base_to_camera_link() const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(deg2rad(pitch_deg), Eigen::Vector3d::UnitY()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

Eigen::Isometry3d CameraMount::base_to_optical() const {
  return base_to_camera_link() * camera_link_to_optical();
}

Sequence generate_sequence(const SequenceConfig& config) {
  const SceneConfig& sc = config.scene;
  const TrajectoryConfig& tc = config.trajectory;
  if (tc.frames < 1) throw std::invalid_argument("generate_sequence: frames must be >= 1");
  if (!(tc.speed > 0.0) || !(tc.clearance > 0.0) || !(tc.max_yaw_rate_deg > 0.0)) {
    throw std::invalid_argument("generate_sequence: speed, clearance, yaw rate must be > 0");
  }
  if (!(config.fps > 0.0)) throw std::invalid_argument("generate_sequence: fps must be > 0");
  if (!config.intrinsics.valid() || config.intrinsics.width < 1 || config.intrinsics.height < 1) {
    throw std::invalid_argument("generate_sequence: invalid intrinsics");
  }
  if (sc.min_width > sc.max_width || sc.min_height > sc.max_height ||
      sc.min_objects > sc.max_objects || sc.min_objects < 0 || tc.min_height > tc.max_height) {
    throw std::invalid_argument("generate_sequence: a min exceeds its max");
  }
  const bool robot = tc.type == TrajectoryType::kRobot;
  if (robot && !(std::abs(tc.mount.pitch_deg) < 90.0 && std::isfinite(tc.mount.x) &&
                 std::isfinite(tc.mount.y))) {
    throw std::invalid_argument("generate_sequence: mount pitch must be within (-90, 90) degrees");
  }
  const SensorConfig& sensor = config.sensor;
  if (!(sensor.read_noise >= 0.0) || !(sensor.shot_noise >= 0.0) ||
      !(sensor.exposure_drift >= 0.0 && sensor.exposure_drift < 1.0) ||
      !(sensor.exposure_step_prob >= 0.0 && sensor.exposure_step_prob <= 1.0) ||
      !(sensor.exposure_step >= 0.0)) {
    throw std::invalid_argument(
        "generate_sequence: noise and exposure step must be >= 0, exposure drift in [0, 1), "
        "step probability in [0, 1]");
  }

  Rng rng(config.seed);
  Sequence seq;
  seq.config = config;
  Scene& scene = seq.scene;
  scene.room_size = Eigen::Vector3d(rng.uniform(sc.min_width, sc.max_width),
                                    rng.uniform(sc.min_width, sc.max_width),
                                    rng.uniform(sc.min_height, sc.max_height));
  const double margin = tc.clearance + 0.05;
  if (std::min(scene.room_size.x(), scene.room_size.y()) < 2 * margin + 1.0) {
    throw std::invalid_argument("generate_sequence: room too small for the clearance");
  }
  const double h_lo = robot ? tc.mount.z : std::max(tc.min_height, tc.clearance);
  const double h_hi =
      robot ? tc.mount.z : std::min(tc.max_height, scene.room_size.z() - tc.clearance);
  if (h_lo > h_hi || h_lo < tc.clearance || h_hi > scene.room_size.z() - tc.clearance) {
    throw std::invalid_argument("generate_sequence: no valid camera height");
  }

  // Room materials: four distinct walls, a patterned floor, a plain ceiling.
  for (int w = 0; w < 4; ++w) {
    scene.room_material[w] =
        add_material(scene, random_material(rng,
                                            {Pattern::kNoise, Pattern::kBricks, Pattern::kTiles,
                                             Pattern::kStripes, Pattern::kMarble, Pattern::kDots},
                                            0.25f, 0.6f, false));
  }
  scene.room_material[4] = add_material(
      scene,
      random_material(rng, {Pattern::kTiles, Pattern::kWood, Pattern::kChecker, Pattern::kBricks},
                      0.3f, 0.7f, false));
  scene.room_material[5] = add_material(
      scene, random_material(rng, {Pattern::kNoise, Pattern::kTiles}, 0.5f, 0.8f, false));
  scene.light_direction = Eigen::Vector3d(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 1.0);
  scene.point_light =
      Eigen::Vector3d(rng.uniform(0.3, 0.7) * scene.room_size.x(),
                      rng.uniform(0.3, 0.7) * scene.room_size.y(), scene.room_size.z() - 0.2);

  PathResult path;
  switch (tc.type) {
    case TrajectoryType::kWalk:
      path = walk_path(rng, scene.room_size, tc, h_lo, h_hi);
      break;
    case TrajectoryType::kOrbit:
      path = orbit_path(rng, scene.room_size, tc, h_lo, h_hi);
      break;
    case TrajectoryType::kPanReturn:
      path = pan_path(rng, scene.room_size, tc, h_lo, h_hi);
      break;
    case TrajectoryType::kRobot:
      path = robot_path(rng, scene.room_size, tc, &seq.base_poses);
      break;
  }
  seq.poses = std::move(path.poses);
  for (int i = 0; i < tc.frames; ++i) seq.stamps.push_back(config.start_time + i / config.fps);

  std::vector<Eigen::Vector3d> cameras;
  cameras.reserve(seq.poses.size());
  for (const auto& p : seq.poses) cameras.push_back(p.translation());
  // The robot's body too: a column over the base up to the camera, so that
  // furniture also stays `clearance` away from it (a rug on the floor may pass).
  for (const auto& b : seq.base_poses) {
    for (double z = tc.clearance + 0.05; z < tc.mount.z; z += tc.clearance) {
      cameras.push_back(b.translation() + Eigen::Vector3d(0, 0, z));
    }
  }
  Placer placer{&scene, &rng, &cameras, tc.clearance, {}};

  // Orbit: a centrepiece the camera circles around.
  if (tc.type == TrajectoryType::kOrbit) {
    const double room_for_it = path.focus_radius - tc.clearance - 0.05;
    if (room_for_it > 0.25) {
      Shape table;
      table.type = ShapeType::kBox;
      table.label = "table";
      const double hx = std::min(0.7, room_for_it * 0.6), hy = std::min(0.5, room_for_it * 0.6);
      table.half_size = Eigen::Vector3d(hx, hy, 0.5 * path.focus.z());
      table.center = Eigen::Vector3d(path.focus.x(), path.focus.y(), table.half_size.z());
      table.yaw = rng.uniform(0.0, kPi);
      table.material = add_material(scene, random_material(rng, kAnyPattern, 0.05f, 0.2f, true));
      if (placer.try_stand(table)) {
        Shape ball;
        ball.type = ShapeType::kSphere;
        ball.label = "ball";
        const double r = std::min(0.2, 0.8 * std::min(hx, hy));
        ball.half_size = Eigen::Vector3d(r, r, r);
        ball.center = table.center + Eigen::Vector3d(0, 0, table.half_size.z() + r);
        ball.material =
            add_material(scene, random_material(rng, kSpherePattern, 0.05f, 0.15f, true));
        placer.try_on_top(ball);
      }
    }
  }

  const int target = rng.uniform_int(sc.min_objects, sc.max_objects);
  int placed = 0;
  for (int attempt = 0; attempt < 400 && placed < target; ++attempt) {
    Shape s = random_standing(rng, scene, 0);
    const bool sphere = s.type == ShapeType::kSphere;
    if (!placer.try_stand(s)) continue;
    Shape& added = scene.shapes.back();
    added.material = add_material(
        scene, random_material(rng, sphere ? kSpherePattern : kAnyPattern, 0.05f, 0.3f, true));
    ++placed;
    // Something on most tables and crates.
    if ((added.label == "table" || added.label == "crate") && rng.bernoulli(0.7)) {
      const Shape base = added;
      Shape top;
      const double r = rng.uniform(0.06, 0.16);
      if (rng.bernoulli(0.5)) {
        top.type = ShapeType::kSphere;
        top.label = "ball";
        top.half_size = Eigen::Vector3d(r, r, r);
      } else {
        top.type = ShapeType::kCylinder;
        top.label = "vase";
        top.half_size = Eigen::Vector3d(r, r, rng.uniform(0.08, 0.25));
      }
      const double fit_x = std::max(0.0, base.half_size.x() - r),
                   fit_y = std::max(0.0, base.half_size.y() - r);
      const Eigen::Vector3d off(rng.uniform(-fit_x, fit_x), rng.uniform(-fit_y, fit_y), 0.0);
      const double c = std::cos(base.yaw), sn = std::sin(base.yaw);
      top.center =
          base.center + Eigen::Vector3d(c * off.x() - sn * off.y(), sn * off.x() + c * off.y(),
                                        base.half_size.z() + top.half_size.z());
      top.material = add_material(
          scene, random_material(rng, top.type == ShapeType::kSphere ? kSpherePattern : kAnyPattern,
                                 0.03f, 0.12f, true));
      placer.try_on_top(top);
    }
  }

  // Pictures on the walls and a rug: thin boxes with busy textures.
  for (int p = 0, attempt = 0; p < sc.pictures && attempt < 60; ++attempt) {
    const int wall = rng.uniform_int(0, 3);
    Shape pic;
    pic.type = ShapeType::kBox;
    pic.label = "picture";
    pic.half_size = Eigen::Vector3d(rng.uniform(0.2, 0.6), 0.015, rng.uniform(0.15, 0.45));
    const Eigen::Vector3d& r = scene.room_size;
    const double along = pic.half_size.x() + 0.1;
    const double z =
        rng.uniform(pic.half_size.z() + 0.8,
                    std::max(pic.half_size.z() + 0.8, r.z() - pic.half_size.z() - 0.2));
    if (wall < 2) {
      pic.yaw = kPi / 2;
      pic.center =
          Eigen::Vector3d(wall == 0 ? 0.015 : r.x() - 0.015, rng.uniform(along, r.y() - along), z);
    } else {
      pic.center =
          Eigen::Vector3d(rng.uniform(along, r.x() - along), wall == 2 ? 0.015 : r.y() - 0.015, z);
    }
    if (pic.center.z() + pic.half_size.z() > r.z() - 0.05) continue;
    pic.material = add_material(scene, random_material(rng, kAnyPattern, 0.04f, 0.15f, true));
    if (placer.try_on_top(pic)) ++p;
  }
  {
    Shape rug;
    rug.type = ShapeType::kBox;
    rug.label = "rug";
    rug.half_size = Eigen::Vector3d(rng.uniform(0.5, 1.0), rng.uniform(0.4, 0.8), 0.004);
    rug.center = Eigen::Vector3d(rng.uniform(1.1, scene.room_size.x() - 1.1),
                                 rng.uniform(1.1, scene.room_size.y() - 1.1), 0.004);
    rug.yaw = rng.uniform(0.0, kPi);
    rug.material = add_material(scene, random_material(rng, kAnyPattern, 0.05f, 0.2f, true));
    placer.try_on_top(rug);
  }
  seq.exposure = exposure_gains(config.sensor, config.seed, seq.stamps);
  return seq;
}

namespace {
// derived_seed stream of the exposure gains (an arbitrary constant).
constexpr uint64_t kExposureStream = 0x6578706f73757265ull;  // "exposure"
}  // namespace

std::vector<double> exposure_gains(const SensorConfig& sensor, uint64_t seed,
                                   const std::vector<double>& stamps) {
  std::vector<double> gains(stamps.size(), 1.0);
  if (!sensor.exposure() || stamps.empty()) return gains;
  Rng rng(derived_seed(seed, kExposureStream));
  const double w1 = 2 * M_PI / rng.uniform(6.0, 12.0), p1 = rng.uniform(0.0, 2 * M_PI);
  const double w2 = 2 * M_PI / rng.uniform(2.5, 5.0), p2 = rng.uniform(0.0, 2 * M_PI);
  const double log_step = std::log1p(sensor.exposure_step);
  double step = 1.0;
  for (size_t i = 0; i < stamps.size(); ++i) {
    if (sensor.exposure_step_prob > 0.0 && rng.bernoulli(sensor.exposure_step_prob)) {
      step = std::exp(rng.uniform(-1.0, 1.0) * log_step);
    }
    const double t = stamps[i] - stamps[0];
    const double wave = 0.6 * std::sin(w1 * t + p1) + 0.4 * std::sin(w2 * t + p2);
    gains[i] = (1.0 + sensor.exposure_drift * wave) * step;
  }
  return gains;
}

}  // namespace long3r::synth
