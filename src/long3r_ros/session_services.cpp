#include "long3r_ros/session_services.hpp"

#include "long3r/dataset/tum_dataset.hpp"

namespace long3r_ros {

SessionServices::SessionServices(ros::NodeHandle& pnh, std::string map_frame, std::string log_name,
                                 Node& node, bool surface)
    : map_frame_(std::move(map_frame)), log_name_(std::move(log_name)), node_(node) {
  reset_srv_ = pnh.advertiseService("reset", &SessionServices::reset, this);
  pause_srv_ = pnh.advertiseService("pause", &SessionServices::pause, this);
  resume_srv_ = pnh.advertiseService("resume", &SessionServices::resume, this);
  save_map_srv_ = pnh.advertiseService("save_map", &SessionServices::saveMap, this);
  if (surface) save_mesh_srv_ = pnh.advertiseService("save_mesh", &SessionServices::saveMesh, this);
  save_trajectory_srv_ =
      pnh.advertiseService("save_trajectory", &SessionServices::saveTrajectory, this);
  save_session_srv_ = pnh.advertiseService("save_session", &SessionServices::saveSession, this);
  load_session_srv_ = pnh.advertiseService("load_session", &SessionServices::loadSession, this);
}

void SessionServices::shutdown() {
  reset_srv_.shutdown();
  pause_srv_.shutdown();
  resume_srv_.shutdown();
  save_map_srv_.shutdown();
  save_mesh_srv_.shutdown();
  save_session_srv_.shutdown();
  load_session_srv_.shutdown();
  save_trajectory_srv_.shutdown();
}

bool SessionServices::reset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  node_.changeSession([](long3r::LiveSession& session) { session.reset("reset requested"); });
  node_.clearQueue();
  res.success = true;
  res.message = "memory, map and path cleared";
  return true;
}

bool SessionServices::pause(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  const bool was = node_.setPaused(true);
  res.success = true;
  res.message = was ? "already paused"
                    : "paused: incoming frames are dropped and counted until ~resume; memory, "
                      "map and path are kept";
  if (!was) ROS_INFO_NAMED(log_name_, "%s", res.message.c_str());
  return true;
}

bool SessionServices::resume(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  const bool was = node_.setPaused(false);
  res.success = true;
  res.message = was ? "resumed; " + std::to_string(node_.pausedDrops()) +
                          " frame(s) dropped while paused so far"
                    : "not paused";
  if (was) ROS_INFO_NAMED(log_name_, "%s", res.message.c_str());
  return true;
}

bool SessionServices::saveMesh(SaveMesh::Request& req, SaveMesh::Response& res) {
  try {
    const long3r::ColoredMesh mesh = node_.surfaceMesh();  // as ~mesh shows it
    long3r::save_mesh_ply(req.path, mesh.vertices, &mesh.colors, mesh.triangles);  // atomic
    res.success = true;
    res.message = "wrote " + std::to_string(mesh.triangles.size()) + " triangles (" + map_frame_ +
                  ") to " + req.path;
  } catch (const std::exception& e) {
    res.success = false;
    res.message = e.what();
  }
  return true;
}

bool SessionServices::saveMap(SaveMap::Request& req, SaveMap::Response& res) {
  try {
    const long3r::MapSnapshot snap = node_.mapSnapshot();            // as ~map shows it
    long3r::save_colored_cloud(req.path, snap.points, snap.colors);  // atomic
    res.success = true;
    res.message = "wrote " + std::to_string(snap.points.size()) + " points (" + map_frame_ +
                  ") to " + req.path;
  } catch (const std::exception& e) {
    res.success = false;
    res.message = e.what();
  }
  return true;
}

bool SessionServices::saveSession(SaveSession::Request& req, SaveSession::Response& res) {
  node_.changeSession([&](long3r::LiveSession& session) {
    try {
      session.save(req.path);  // atomic; publishes the pending frame first
      res.success = true;
      res.message = "saved " + std::to_string(session.reconstruction().frames_pushed()) +
                    " frames, " + std::to_string(session.reconstruction().map().size()) +
                    " map points to " + req.path;
      node_.sessionFileChanged("saved to " + req.path);
    } catch (const std::exception& e) {
      res.success = false;
      res.message = e.what();
      ROS_ERROR_NAMED(log_name_, "~save_session: %s", e.what());
    }
  });
  return true;
}

bool SessionServices::loadSession(LoadSession::Request& req, LoadSession::Response& res) {
  node_.changeSession([&](long3r::LiveSession& session) {
    try {
      session.load(req.path);  // all or nothing
      res.success = true;
      res.message = "loaded " + std::to_string(session.reconstruction().frames_pushed()) +
                    " frames, " + std::to_string(session.reconstruction().map().size()) +
                    " map points from " + req.path + "; the next frames continue it";
      node_.sessionFileChanged("loaded from " + req.path);
    } catch (const std::exception& e) {
      res.success = false;
      res.message = e.what() + std::string("; the running session is kept");
      ROS_ERROR_NAMED(log_name_, "~load_session: %s", res.message.c_str());
    }
  });
  if (res.success) node_.clearQueue();  // frames queued for the old stream
  return true;
}

bool SessionServices::saveTrajectory(SaveTrajectory::Request& req, SaveTrajectory::Response& res) {
  long3r::PoseTrajectory trajectory;
  std::string what;
  node_.readSession([&](const long3r::LiveSession& session, const RobotFrames& frames) {
    for (const auto& [stamp, T_W_C] : session.reconstruction().trajectory()) {
      trajectory.stamps.push_back(stamp);
      trajectory.poses.push_back(frames.bodyInMap(T_W_C, ros::Time(stamp)));
    }
    what = "poses of " + frames.bodyFrame() + " in " + map_frame_;
  });
  try {
    long3r::write_tum_trajectory(req.path, trajectory, "long3r_ros ~path: " + what);  // atomic
    res.success = true;
    res.message = "wrote " + std::to_string(trajectory.size()) + " " + what + " to " + req.path;
  } catch (const std::exception& e) {
    res.success = false;
    res.message = e.what();
  }
  return true;
}

}  // namespace long3r_ros
