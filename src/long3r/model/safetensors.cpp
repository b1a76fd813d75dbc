// safetensors reading and atomic writing; see include/long3r/model/safetensors.hpp.
//
// Tensor bytes are copied straight between the file and tensor storage, which
// assumes a little-endian host (the format is little-endian); a big-endian
// host is refused rather than producing byte-swapped values.
#include "long3r/model/safetensors.hpp"

#include <ATen/ATen.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>
#include <nlohmann/json.hpp>
#include <vector>

namespace long3r {

namespace {

bool host_is_little_endian() {
  const uint16_t one = 1;
  unsigned char first;
  std::memcpy(&first, &one, 1);
  return first == 1;
}

void require_little_endian(const std::string& path) {
  if (!host_is_little_endian()) {
    throw CheckpointError(path + ": safetensors I/O needs a little-endian host");
  }
}

at::ScalarType to_scalar_type(DType d) {
  switch (d) {
    case DType::kF32:
      return at::kFloat;
    case DType::kF16:
      return at::kHalf;
    case DType::kBF16:
      return at::kBFloat16;
    case DType::kI64:
      return at::kLong;
  }
  return at::kFloat;
}

bool from_scalar_type(at::ScalarType s, DType* d) {
  switch (s) {
    case at::kFloat:
      *d = DType::kF32;
      return true;
    case at::kHalf:
      *d = DType::kF16;
      return true;
    case at::kBFloat16:
      *d = DType::kBF16;
      return true;
    case at::kLong:
      *d = DType::kI64;
      return true;
    default:
      return false;
  }
}

std::string errno_text() { return std::strerror(errno); }

// Closes the descriptor on scope exit.
struct Fd {
  int fd = -1;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

// Reads exactly n bytes at offset, or throws.
void read_at(int fd, uint64_t offset, void* dst, uint64_t n, const std::string& path,
             const std::string& what) {
  auto* p = static_cast<char*>(dst);
  while (n > 0) {
    const std::size_t chunk = static_cast<std::size_t>(std::min<uint64_t>(n, 1u << 30));
    const ssize_t r = ::pread(fd, p, chunk, static_cast<off_t>(offset));
    if (r < 0) {
      if (errno == EINTR) continue;
      throw CheckpointError(path + ": read error in " + what + ": " + errno_text());
    }
    if (r == 0) {
      throw CheckpointError(path + ": unexpected end of file in " + what +
                            " (file changed while reading?)");
    }
    p += r;
    offset += static_cast<uint64_t>(r);
    n -= static_cast<uint64_t>(r);
  }
}

void write_all(int fd, const void* src, std::size_t n, const std::string& path) {
  const auto* p = static_cast<const char*>(src);
  while (n > 0) {
    const std::size_t chunk = std::min<std::size_t>(n, 1u << 30);
    const ssize_t w = ::write(fd, p, chunk);
    if (w < 0) {
      if (errno == EINTR) continue;
      throw CheckpointError(path + ": write error: " + errno_text());
    }
    p += w;
    n -= static_cast<std::size_t>(w);
  }
}

}  // namespace

TensorFile load_safetensors(const std::string& path) {
  require_little_endian(path);
  Fd f;
  f.fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (f.fd < 0) throw CheckpointError(path + ": cannot open: " + errno_text());
  struct stat st;
  if (::fstat(f.fd, &st) != 0) throw CheckpointError(path + ": cannot stat: " + errno_text());
  if (!S_ISREG(st.st_mode)) throw CheckpointError(path + ": not a regular file");
  const uint64_t file_size = static_cast<uint64_t>(st.st_size);

  // Read the length field, then the header only if its length is plausible;
  // otherwise the parser reports the bad length from the 8 bytes alone.
  std::vector<uint8_t> head(static_cast<std::size_t>(std::min<uint64_t>(file_size, 8)));
  read_at(f.fd, 0, head.data(), head.size(), path, "the header length");
  if (head.size() == 8) {
    const uint64_t n = decode_header_length(head.data());
    if (n <= kMaxSafetensorsHeaderBytes && n <= file_size - 8) {
      head.resize(static_cast<std::size_t>(8 + n));
      read_at(f.fd, 8, head.data() + 8, n, path, "the header");
    }
  }
  SafetensorsHeader h;
  try {
    h = parse_safetensors_header(head.data(), head.size(), file_size);
  } catch (const CheckpointError& e) {
    throw CheckpointError(path + ": " + e.what());
  }

  TensorFile out;
  out.metadata = std::move(h.metadata);
  for (const TensorEntry& e : h.tensors) {
    at::Tensor t = at::empty(e.shape, at::TensorOptions().dtype(to_scalar_type(e.dtype)));
    const uint64_t nbytes = e.end - e.begin;
    if (nbytes > 0) {
      read_at(f.fd, h.data_offset + e.begin, t.data_ptr(), nbytes, path,
              "tensor " + quoted(e.name));
    }
    out.tensors.emplace(e.name, std::move(t));
  }
  return out;
}

void save_safetensors(const std::string& path, const std::map<std::string, at::Tensor>& tensors,
                      const std::map<std::string, std::string>& metadata) {
  require_little_endian(path);

  // Host-side contiguous copies, checked before anything is written.
  struct Item {
    const std::string* name;
    DType dtype;
    at::Tensor t;
  };
  std::vector<Item> items;
  items.reserve(tensors.size());
  for (const auto& kv : tensors) {
    if (kv.first == "__metadata__") {
      throw CheckpointError(path + ": \"__metadata__\" cannot be a tensor name");
    }
    if (!kv.second.defined()) {
      throw CheckpointError(path + ": tensor " + quoted(kv.first) + " is undefined");
    }
    if (kv.second.layout() != at::kStrided) {
      throw CheckpointError(path + ": tensor " + quoted(kv.first) +
                            " is not a dense (strided) tensor");
    }
    DType d;
    if (!from_scalar_type(kv.second.scalar_type(), &d)) {
      throw CheckpointError(path + ": tensor " + quoted(kv.first) + " has dtype " +
                            std::string(c10::toString(kv.second.scalar_type())) +
                            "; only float32, float16, bfloat16 and int64 can be saved");
    }
    items.push_back({&kv.first, d, kv.second.detach().to(at::kCPU).contiguous()});
  }
  // Data order: larger items first, then by name, so that every tensor starts
  // at a multiple of its item size without gaps (the data section starts
  // 8-aligned). The header lists the keys sorted by name.
  std::vector<const Item*> order;
  for (const Item& it : items) order.push_back(&it);
  std::stable_sort(order.begin(), order.end(), [](const Item* a, const Item* b) {
    return dtype_size(a->dtype) > dtype_size(b->dtype);
  });
  std::map<std::string, std::pair<uint64_t, uint64_t>> ranges;
  uint64_t offset = 0;
  for (const Item* it : order) {
    const uint64_t nbytes = static_cast<uint64_t>(it->t.numel()) * dtype_size(it->dtype);
    ranges[*it->name] = {offset, offset + nbytes};
    offset += nbytes;
  }

  // Metadata first, then the tensors by name (std::map order).
  nlohmann::ordered_json root = nlohmann::ordered_json::object();
  if (!metadata.empty()) {
    nlohmann::ordered_json meta = nlohmann::ordered_json::object();
    for (const auto& kv : metadata) meta[kv.first] = kv.second;
    root["__metadata__"] = std::move(meta);
  }
  for (const Item& it : items) {
    const auto& r = ranges[*it.name];
    root[*it.name] = {{"dtype", dtype_name(it.dtype)},
                      {"shape", it.t.sizes().vec()},
                      {"data_offsets", {r.first, r.second}}};
  }
  std::string header;
  try {
    header = root.dump();
  } catch (const nlohmann::ordered_json::type_error&) {
    throw CheckpointError(path + ": a tensor name or metadata entry is not valid UTF-8");
  }
  header.append((8 - header.size() % 8) % 8, ' ');
  if (header.size() > kMaxSafetensorsHeaderBytes) {
    throw CheckpointError(path + ": header of " + std::to_string(header.size()) +
                          " bytes exceeds the format limit");
  }

  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  Fd f;
  f.fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (f.fd < 0) throw CheckpointError(tmp + ": cannot create: " + errno_text());
  try {
    uint8_t len[8];
    encode_header_length(header.size(), len);
    write_all(f.fd, len, 8, tmp);
    write_all(f.fd, header.data(), header.size(), tmp);
    for (const Item* it : order) {
      const uint64_t nbytes = static_cast<uint64_t>(it->t.numel()) * dtype_size(it->dtype);
      if (nbytes > 0) write_all(f.fd, it->t.data_ptr(), static_cast<std::size_t>(nbytes), tmp);
    }
    if (::fsync(f.fd) != 0) throw CheckpointError(tmp + ": fsync failed: " + errno_text());
    const int fd = f.fd;
    f.fd = -1;
    if (::close(fd) != 0) throw CheckpointError(tmp + ": close failed: " + errno_text());
    if (::rename(tmp.c_str(), path.c_str()) != 0) {
      throw CheckpointError(path + ": cannot rename " + tmp + " into place: " + errno_text());
    }
  } catch (...) {
    ::unlink(tmp.c_str());
    throw;
  }
  // Make the rename itself durable; failure here leaves a complete file, so it
  // is not reported.
  std::string dir = ".";
  const auto slash = path.find_last_of('/');
  if (slash != std::string::npos) dir = slash == 0 ? "/" : path.substr(0, slash);
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

}  // namespace long3r
