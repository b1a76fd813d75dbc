// Ray casting against the room and the furniture (analytic intersections).
#include <algorithm>
#include <cmath>
#include <limits>

#include "long3r/synth/geometry.hpp"

namespace long3r::synth {

namespace {

constexpr double kEps = 1e-9;

// World -> shape frame for yawed boxes (rotation about z by -yaw).
inline Eigen::Vector3d to_local(const Eigen::Vector3d& v, double c, double s) {
  return {c * v.x() + s * v.y(), -s * v.x() + c * v.y(), v.z()};
}
inline Eigen::Vector3d to_world(const Eigen::Vector3d& v, double c, double s) {
  return {c * v.x() - s * v.y(), s * v.x() + c * v.y(), v.z()};
}

bool hit_box(const Shape& b, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_max,
             double* t_out, int* face_out, Eigen::Vector3d* n_out, Eigen::Vector3d* local_out) {
  const double c = std::cos(b.yaw), s = std::sin(b.yaw);
  const Eigen::Vector3d ol = to_local(o - b.center, c, s);
  const Eigen::Vector3d dl = to_local(d, c, s);
  double t_near = -std::numeric_limits<double>::infinity();
  double t_far = std::numeric_limits<double>::infinity();
  int axis = -1;
  for (int k = 0; k < 3; ++k) {
    const double h = b.half_size(k);
    if (std::abs(dl(k)) < 1e-15) {
      if (ol(k) < -h || ol(k) > h) return false;
      continue;
    }
    double t1 = (-h - ol(k)) / dl(k);
    double t2 = (h - ol(k)) / dl(k);
    if (t1 > t2) std::swap(t1, t2);
    if (t1 > t_near) {
      t_near = t1;
      axis = k;
    }
    t_far = std::min(t_far, t2);
    if (t_near > t_far) return false;
  }
  if (axis < 0 || t_near <= kEps || t_near >= t_max) return false;
  *t_out = t_near;
  // Entering through the min side when moving +, the max side otherwise.
  *face_out = 2 * axis + (dl(axis) > 0 ? 0 : 1);
  Eigen::Vector3d nl = Eigen::Vector3d::Zero();
  nl(axis) = dl(axis) > 0 ? -1.0 : 1.0;
  *n_out = to_world(nl, c, s);
  *local_out = ol + t_near * dl;
  return true;
}

bool hit_cylinder(const Shape& cy, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_max,
                  double* t_out, int* face_out, Eigen::Vector3d* n_out,
                  Eigen::Vector3d* local_out) {
  const double r = cy.half_size.x(), hh = cy.half_size.z();
  const Eigen::Vector3d ol = o - cy.center;
  double best = t_max;
  int face = -1;
  const double a = d.x() * d.x() + d.y() * d.y();
  if (a > 1e-18) {
    const double bb = ol.x() * d.x() + ol.y() * d.y();
    const double cc = ol.x() * ol.x() + ol.y() * ol.y() - r * r;
    const double disc = bb * bb - a * cc;
    if (disc >= 0.0) {
      const double t = (-bb - std::sqrt(disc)) / a;
      const double z = ol.z() + t * d.z();
      if (t > kEps && t < best && z >= -hh && z <= hh) {
        best = t;
        face = 0;
      }
    }
  }
  if (std::abs(d.z()) > 1e-15) {
    for (int cap = 0; cap < 2; ++cap) {
      const double zc = cap == 0 ? -hh : hh;
      const double t = (zc - ol.z()) / d.z();
      if (t <= kEps || t >= best) continue;
      const double x = ol.x() + t * d.x(), y = ol.y() + t * d.y();
      if (x * x + y * y <= r * r) {
        best = t;
        face = 1 + cap;
      }
    }
  }
  if (face < 0) return false;
  const Eigen::Vector3d pl = ol + best * d;
  *t_out = best;
  *face_out = face;
  if (face == 0) {
    *n_out = Eigen::Vector3d(pl.x(), pl.y(), 0.0).normalized();
  } else {
    *n_out = Eigen::Vector3d(0.0, 0.0, face == 1 ? -1.0 : 1.0);
  }
  *local_out = pl;
  return true;
}

bool hit_sphere(const Shape& sp, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_max,
                double* t_out, Eigen::Vector3d* n_out, Eigen::Vector3d* local_out) {
  const double r = sp.half_size.x();
  const Eigen::Vector3d ol = o - sp.center;
  const double a = d.squaredNorm();
  const double bb = ol.dot(d);
  const double cc = ol.squaredNorm() - r * r;
  const double disc = bb * bb - a * cc;
  if (disc < 0.0) return false;
  const double t = (-bb - std::sqrt(disc)) / a;
  if (t <= kEps || t >= t_max) return false;
  *t_out = t;
  *local_out = ol + t * d;
  *n_out = *local_out / r;
  return true;
}

}  // namespace

double Shape::distance(const Eigen::Vector3d& p) const {
  const Eigen::Vector3d q = p - center;
  switch (type) {
    case ShapeType::kBox: {
      const Eigen::Vector3d l = to_local(q, std::cos(yaw), std::sin(yaw));
      const Eigen::Vector3d e = (l.cwiseAbs() - half_size).cwiseMax(0.0);
      return e.norm();
    }
    case ShapeType::kCylinder: {
      const double radial = std::max(0.0, std::hypot(q.x(), q.y()) - half_size.x());
      const double axial = std::max(0.0, std::abs(q.z()) - half_size.z());
      return std::hypot(radial, axial);
    }
    case ShapeType::kSphere:
      return std::max(0.0, q.norm() - half_size.x());
  }
  return 0.0;
}

bool intersect(const Scene& scene, const Eigen::Vector3d& o, const Eigen::Vector3d& d, Hit* hit) {
  // Room (seen from inside): the nearest exit plane.
  double best = std::numeric_limits<double>::infinity();
  int room_face = -1;
  for (int k = 0; k < 3; ++k) {
    if (std::abs(d(k)) < 1e-15) continue;
    const double bound = d(k) > 0 ? scene.room_size(k) : 0.0;
    const double t = (bound - o(k)) / d(k);
    if (t > kEps && t < best) {
      best = t;
      room_face = 2 * k + (d(k) > 0 ? 1 : 0);
    }
  }

  int shape_index = -1, shape_face = 0;
  Eigen::Vector3d n, local;
  for (size_t i = 0; i < scene.shapes.size(); ++i) {
    const Shape& s = scene.shapes[i];
    double t;
    int face = 0;
    Eigen::Vector3d ni, li;
    bool ok = false;
    switch (s.type) {
      case ShapeType::kBox:
        ok = hit_box(s, o, d, best, &t, &face, &ni, &li);
        break;
      case ShapeType::kCylinder:
        ok = hit_cylinder(s, o, d, best, &t, &face, &ni, &li);
        break;
      case ShapeType::kSphere:
        ok = hit_sphere(s, o, d, best, &t, &ni, &li);
        break;
    }
    if (ok) {
      best = t;
      shape_index = static_cast<int>(i);
      shape_face = face;
      n = ni;
      local = li;
    }
  }

  if (shape_index < 0 && room_face < 0) return false;
  hit->t = best;
  hit->point = o + best * d;
  if (shape_index >= 0) {
    const Shape& s = scene.shapes[shape_index];
    hit->normal = n;
    hit->local = local;
    hit->material = s.material;
    hit->surface_id = 16 * (shape_index + 1) + shape_face;
    switch (s.type) {
      case ShapeType::kBox: {
        const int axis = shape_face / 2;
        hit->uv = Eigen::Vector2d(local((axis + 1) % 3), local((axis + 2) % 3));
        break;
      }
      case ShapeType::kCylinder:
        hit->uv =
            shape_face == 0
                ? Eigen::Vector2d(std::atan2(local.y(), local.x()) * s.half_size.x(), local.z())
                : Eigen::Vector2d(local.x(), local.y());
        break;
      case ShapeType::kSphere:
        // Latitude first: patterns that vary along u only have no seam.
        hit->uv = Eigen::Vector2d(
            std::asin(std::clamp(local.z() / s.half_size.x(), -1.0, 1.0)) * s.half_size.x(),
            std::atan2(local.y(), local.x()) * s.half_size.x());
        break;
    }
  } else {
    const int axis = room_face / 2;
    hit->normal = Eigen::Vector3d::Zero();
    hit->normal(axis) = (room_face % 2 == 0) ? 1.0 : -1.0;
    hit->local = hit->point;
    hit->material = scene.room_material[room_face];
    hit->surface_id = room_face;
    // Walls: (horizontal coordinate, height); floor and ceiling: (x, y).
    if (axis == 0) hit->uv = Eigen::Vector2d(hit->point.y(), hit->point.z());
    if (axis == 1) hit->uv = Eigen::Vector2d(hit->point.x(), hit->point.z());
    if (axis == 2) hit->uv = Eigen::Vector2d(hit->point.x(), hit->point.y());
  }
  return true;
}

}  // namespace long3r::synth
