// ~map (the accumulated map, thinned for display) and ~grid (its occupancy
// grid), both in map_frame and latched; with surface_enabled also ~surface
// (the fused surface's coloured points) and ~mesh (its triangles, an rviz
// marker), latched too. ~map goes out as PCL's coloured cloud
// (pcl::PointXYZRGB, through pcl_conversions), filtered by PCL for display. Each is built only
// while subscribed and only when the map changed since it was last sent.
//
// ~grid is the session's 3-D occupancy (OctoMap) projected in the band above
// the floor. Only a z-up map (with base_frame) has a floor to stand on, so
// ~grid needs base_frame; gridStatus() says why there is no grid, or that it
// is not in metres yet, for the diagnostics.
#pragma once

#include <ros/ros.h>

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "long3r/mapping/occupancy_map.hpp"
#include "long3r/mapping/tsdf_volume.hpp"
#include "long3r/mapping/voxel_map.hpp"
#include "long3r/pipeline/live_session.hpp"
#include "long3r_ros/log_throttle.hpp"

namespace long3r_ros {

class MapPublisher {
 public:
  struct Config {
    std::string map_frame;
    double display_voxel_m = 0.0;        // ~map thinned to this voxel; 0 = the map's own
    int display_outlier_neighbours = 0;  // ~map without isolated points; 0 = off
    double display_outlier_stddev = 1.0;
    bool z_up = false;  // base_frame is set
    long3r::GridProjectionConfig grid;
    bool surface = false;  // surface_enabled: ~surface and ~mesh
  };

  MapPublisher(ros::NodeHandle& pnh, Config config, Warn warn);

  // Whether the map at `revision` (a count that grows with every change) is
  // to be published; the caller takes a snapshot only then.
  bool wants(std::uint64_t revision) const;
  void publish(long3r::MapSnapshot map, std::uint64_t revision);
  // ~grid at the occupancy's `revision`, projected by `project` only while
  // subscribed and changed since last sent.
  bool gridWanted(std::uint64_t revision) const;
  void publishGrid(std::uint64_t revision,
                   const std::function<long3r::LiveSession::GridProjection()>& project,
                   bool metric);
  // ~surface and ~mesh at the surface's `revision`: each taken (by its
  // function) and sent only while subscribed and changed since last sent.
  void publishSurface(std::uint64_t revision, const std::function<long3r::ColoredPoints()>& points,
                      const std::function<long3r::ColoredMesh()>& mesh);
  // Publishes nothing while the map is not in metres (output_units.hpp);
  // the grid's status says why.
  void hold(const std::string& why);
  std::string gridStatus() const;

 private:
  bool cloudWanted(std::uint64_t revision) const;

  Config config_;
  Warn warn_;
  ros::Publisher map_pub_, grid_pub_, surface_pub_, mesh_pub_;
  std::uint64_t map_revision_ = 0, grid_revision_ = 0;
  std::uint64_t surface_revision_ = 0, mesh_revision_ = 0;
  std::string grid_status_ = "not subscribed";
};

}  // namespace long3r_ros
