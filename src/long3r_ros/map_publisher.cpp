#include "long3r_ros/map_publisher.hpp"

#include <nav_msgs/OccupancyGrid.h>
#include <pcl_conversions/pcl_conversions.h>
#include <sensor_msgs/PointCloud2.h>
#include <visualization_msgs/Marker.h>
#include <boost/make_shared.hpp>

#include <cstdio>
#include <exception>
#include <utility>

#include "long3r_ros/conversions.hpp"

namespace long3r_ros {

MapPublisher::MapPublisher(ros::NodeHandle& pnh, Config config, Warn warn)
    : config_(std::move(config)), warn_(std::move(warn)) {
  map_pub_ = pnh.advertise<sensor_msgs::PointCloud2>("map", 1, /*latch=*/true);
  grid_pub_ = pnh.advertise<nav_msgs::OccupancyGrid>("grid", 1, /*latch=*/true);
  if (config_.surface) {
    surface_pub_ = pnh.advertise<sensor_msgs::PointCloud2>("surface", 1, /*latch=*/true);
    mesh_pub_ = pnh.advertise<visualization_msgs::Marker>("mesh", 1, /*latch=*/true);
  }
}

void MapPublisher::publishSurface(std::uint64_t revision,
                                  const std::function<long3r::ColoredPoints()>& points,
                                  const std::function<long3r::ColoredMesh()>& mesh) {
  if (!config_.surface) return;
  std_msgs::Header header;
  header.stamp = ros::Time::now();
  header.frame_id = config_.map_frame;
  if (surface_pub_.getNumSubscribers() > 0 && revision != surface_revision_) {
    surface_revision_ = revision;
    auto msg = boost::make_shared<sensor_msgs::PointCloud2>();
    pcl::toROSMsg(toPclCloud(points()), *msg);
    msg->header = header;
    surface_pub_.publish(msg);
  }
  if (mesh_pub_.getNumSubscribers() > 0 && revision != mesh_revision_) {
    mesh_revision_ = revision;
    mesh_pub_.publish(boost::make_shared<visualization_msgs::Marker>(toMeshMarker(mesh(), header)));
  }
}

bool MapPublisher::gridWanted(std::uint64_t revision) const {
  return grid_pub_.getNumSubscribers() > 0 && revision != grid_revision_;
}

bool MapPublisher::cloudWanted(std::uint64_t revision) const {
  return map_pub_.getNumSubscribers() > 0 && revision != map_revision_;
}

bool MapPublisher::wants(std::uint64_t revision) const { return cloudWanted(revision); }

std::string MapPublisher::gridStatus() const {
  return grid_pub_.getNumSubscribers() > 0 ? grid_status_ : "not subscribed";
}

void MapPublisher::publish(long3r::MapSnapshot map, std::uint64_t revision) {
  if (!cloudWanted(revision)) return;
  map_revision_ = revision;
  MapCloud cloud = toPclCloud(map);
  downsampleForDisplay(cloud, config_.display_voxel_m);
  removeIsolatedPoints(cloud, config_.display_outlier_neighbours, config_.display_outlier_stddev);
  // By pointer: subscribers in the same nodelet manager share it without a copy.
  auto msg = boost::make_shared<sensor_msgs::PointCloud2>();
  pcl::toROSMsg(cloud, *msg);
  msg->header.stamp = ros::Time::now();
  msg->header.frame_id = config_.map_frame;
  map_pub_.publish(msg);
}

void MapPublisher::hold(const std::string& why) { grid_status_ = "none: " + why; }

void MapPublisher::publishGrid(std::uint64_t revision,
                               const std::function<long3r::LiveSession::GridProjection()>& project,
                               bool metric) {
  if (!gridWanted(revision)) return;
  grid_revision_ = revision;
  if (!config_.z_up) {
    grid_status_ = "none: needs base_frame (the map is z-up only then)";
    return;
  }
  try {
    const long3r::LiveSession::GridProjection p = project();
    const long3r::OccupancyGrid& g = p.grid;
    std_msgs::Header header;
    header.stamp = ros::Time::now();
    header.frame_id = config_.map_frame;
    if (g.width > 0) grid_pub_.publish(toOccupancyGrid(g, header));
    char floor[96];
    std::snprintf(floor, sizeof floor, "floor at z = %.2f m (%s)", p.floor_z_m,
                  p.floor_fitted ? "fitted" : "the base's");
    grid_status_ = std::to_string(g.width) + " x " + std::to_string(g.height) + " cells, " +
                   std::to_string(g.occupied) + " occupied, " + std::to_string(g.free) + " free, " +
                   floor + (metric ? "" : "; in model units");
  } catch (const std::exception& e) {
    grid_status_ = std::string("not published: ") + e.what();
    warn_("grid", "~grid " + grid_status_);
  }
}

}  // namespace long3r_ros
