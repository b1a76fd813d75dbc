// Session files; see include/long3r/pipeline/session.hpp.
#include "long3r/pipeline/session.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <vector>

#include "long3r/model/loading/safetensors.hpp"

namespace long3r {
namespace {

std::string round_trip_text(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// Leaf values of a JSON document by path ("dust3r.enc_depth").
void flatten(const nlohmann::ordered_json& j, const std::string& path,
             std::map<std::string, std::string>& out) {
  if (j.is_object() && !j.empty()) {
    for (auto it = j.begin(); it != j.end(); ++it) {
      flatten(it.value(), path.empty() ? it.key() : path + "." + it.key(), out);
    }
  } else {
    out[path] = j.dump();
  }
}

// "a.b: X in the file, Y here; ..." for the fields that differ.
std::string config_difference(const std::string& saved, const std::string& here) {
  std::map<std::string, std::string> a, b;
  try {
    flatten(nlohmann::ordered_json::parse(saved), "", a);
    flatten(nlohmann::ordered_json::parse(here), "", b);
  } catch (const nlohmann::json::exception&) {
    return "the configuration in the file is not valid JSON";
  }
  std::vector<std::string> diffs;
  for (const auto& [key, value] : a) {
    const auto it = b.find(key);
    if (it == b.end()) {
      diffs.push_back(key + ": " + value + " in the file, absent here");
    } else if (it->second != value) {
      diffs.push_back(key + ": " + value + " in the file, " + it->second + " here");
    }
  }
  for (const auto& [key, value] : b) {
    if (!a.count(key)) diffs.push_back(key + ": absent in the file, " + value + " here");
  }
  std::string text;
  for (std::size_t i = 0; i < diffs.size() && i < 6; ++i) text += (i ? "; " : "") + diffs[i];
  if (diffs.size() > 6) text += "; and " + std::to_string(diffs.size() - 6) + " more";
  return text;
}

const std::string& need(const std::map<std::string, std::string>& metadata, const std::string& key,
                        const std::string& path) {
  const auto it = metadata.find(key);
  if (it == metadata.end()) {
    throw SessionError(path + ": not a complete session file (metadata \"" + key + "\" missing)");
  }
  return it->second;
}

void check_format(const std::map<std::string, std::string>& metadata, const std::string& path) {
  const auto it = metadata.find("format");
  if (it == metadata.end() || it->second != kSessionFormat) {
    throw SessionError(path +
                       ": not a long3r session file (a model checkpoint or another "
                       "safetensors file?)");
  }
  const std::string& version = need(metadata, "format_version", path);
  if (version != kSessionFormatVersion && version != kSessionFormatVersionOldest) {
    throw SessionError(path + ": session format version " + version + ", this build reads " +
                       kSessionFormatVersionOldest + " to " + kSessionFormatVersion);
  }
}

}  // namespace

void write_session(const std::string& path, const SessionIdentity& identity, const StateDict& state,
                   const std::map<std::string, std::string>& summary) {
  if (identity.model.weights.empty()) {
    throw SessionError("session not saved to " + path + ": the " + identity.model.variant +
                       " model's weights were not loaded from a checkpoint, so no later run "
                       "could tell that it continues with the same model");
  }
  std::map<std::string, std::string> metadata = summary;
  metadata["format"] = kSessionFormat;
  metadata["format_version"] = kSessionFormatVersion;
  metadata["model.variant"] = identity.model.variant;
  metadata["model.config"] = identity.model.config_json;
  metadata["model.weights"] = identity.model.weights;
  metadata["input_width"] = std::to_string(identity.input_width);
  metadata["input_height"] = std::to_string(identity.input_height);
  metadata["voxel_size_m"] = round_trip_text(identity.voxel_size_m);
  try {
    save_safetensors(path, state, metadata);
  } catch (const std::exception& e) {
    throw SessionError(std::string("session not saved: ") + e.what());
  }
}

std::map<std::string, std::string> read_session_metadata(const std::string& path) {
  std::map<std::string, std::string> metadata;
  try {
    metadata = read_safetensors_metadata(path);
  } catch (const CheckpointError& e) {
    throw SessionError(std::string("session not loaded: ") + e.what());
  }
  check_format(metadata, path);
  return metadata;
}

StateDict read_session(const std::string& path, const SessionIdentity& expected) {
  // The header first: a foreign or mismatched file is refused before its
  // tensors are read.
  const std::map<std::string, std::string> metadata = read_session_metadata(path);
  auto refuse = [&](const std::string& what) {
    throw SessionError(path + ": made by " + what +
                       "; sessions continue only with the model and "
                       "settings that made them");
  };
  const std::string& variant = need(metadata, "model.variant", path);
  if (variant != expected.model.variant) {
    refuse("a " + variant + " model, this one is " + expected.model.variant);
  }
  const std::string& config = need(metadata, "model.config", path);
  if (config != expected.model.config_json) {
    refuse("a model of another configuration (" +
           config_difference(config, expected.model.config_json) + ")");
  }
  const std::string& weights = need(metadata, "model.weights", path);
  if (weights.empty() || weights != expected.model.weights) {
    refuse("other weights (fingerprint " + (weights.empty() ? "none" : weights) +
           ", this model's " + (expected.model.weights.empty() ? "none" : expected.model.weights) +
           ")");
  }
  const std::string size =
      need(metadata, "input_width", path) + "x" + need(metadata, "input_height", path);
  const std::string here =
      std::to_string(expected.input_width) + "x" + std::to_string(expected.input_height);
  if (size != here) refuse("a model input size of " + size + ", this one " + here);
  const std::string& voxel = need(metadata, "voxel_size_m", path);
  if (voxel != round_trip_text(expected.voxel_size_m)) {
    refuse("a map voxel size of " + voxel + " m, this one " +
           round_trip_text(expected.voxel_size_m) + " m");
  }
  try {
    return load_safetensors(path).tensors;
  } catch (const CheckpointError& e) {
    throw SessionError(std::string("session not loaded: ") + e.what());
  }
}

}  // namespace long3r
