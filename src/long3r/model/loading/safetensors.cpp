// safetensors reading and atomic writing; see include/long3r/model/loading/safetensors.hpp.
//
// Tensor bytes are copied straight between the file and tensor storage, which
// assumes a little-endian host (the format is little-endian); a big-endian
// host is refused rather than producing byte-swapped values.
#include "long3r/model/loading/safetensors.hpp"

#include <ATen/ATen.h>
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <vector>

#include "long3r/io/atomic_file.hpp"

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
    case DType::kF64:
      return at::kDouble;
    case DType::kU8:
      return at::kByte;
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
    case at::kDouble:
      *d = DType::kF64;
      return true;
    case at::kByte:
      *d = DType::kU8;
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

// Opens a checkpoint: refuses, before reading a byte, what is not a regular
// readable file (a directory; a FIFO, whose open would block until a writer
// comes; a device), and reads its validated header.
struct OpenedFile {
  Fd f;
  SafetensorsHeader header;
};
void open_checkpoint(const std::string& path, OpenedFile* out) {
  require_little_endian(path);
  struct stat st;
  if (::stat(path.c_str(), &st) != 0)
    throw CheckpointError(path + ": cannot open: " + errno_text());
  if (S_ISDIR(st.st_mode)) throw CheckpointError(path + ": is a directory, not a checkpoint file");
  if (!S_ISREG(st.st_mode)) throw CheckpointError(path + ": not a regular file");
  Fd& f = out->f;
  // O_NONBLOCK: should the path have become a FIFO since the stat, open must not wait.
  f.fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (f.fd < 0) throw CheckpointError(path + ": cannot open: " + errno_text());
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
  try {
    out->header = parse_safetensors_header(head.data(), head.size(), file_size);
  } catch (const CheckpointError& e) {
    throw CheckpointError(path + ": " + e.what());
  }
}

}  // namespace

std::map<std::string, std::string> read_safetensors_metadata(const std::string& path) {
  OpenedFile file;
  open_checkpoint(path, &file);
  return std::move(file.header.metadata);
}

TensorFile load_safetensors(const std::string& path) {
  OpenedFile file;
  open_checkpoint(path, &file);
  const Fd& f = file.f;
  SafetensorsHeader& h = file.header;

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

namespace {

// A private mapping of a whole file, unmapped with its last view. Live
// mappings are registered so that release_mapped() only ever touches them.
class Mapping {
 public:
  Mapping(int fd, std::size_t size, const std::string& path) : size_(size) {
    void* p = ::mmap(nullptr, size, PROT_READ | PROT_WRITE, MAP_PRIVATE, fd, 0);
    if (p == MAP_FAILED) throw CheckpointError(path + ": cannot map the file: " + errno_text());
    base_ = static_cast<char*>(p);
    std::lock_guard<std::mutex> lock(registry_mutex());
    registry()[reinterpret_cast<std::uintptr_t>(base_)] = size_;
  }
  ~Mapping() {
    {
      std::lock_guard<std::mutex> lock(registry_mutex());
      registry().erase(reinterpret_cast<std::uintptr_t>(base_));
    }
    ::munmap(base_, size_);
  }
  Mapping(const Mapping&) = delete;
  Mapping& operator=(const Mapping&) = delete;
  char* base() const { return base_; }

  static std::mutex& registry_mutex() {
    static std::mutex m;
    return m;
  }
  // base -> size of every live mapping.
  static std::map<std::uintptr_t, std::size_t>& registry() {
    static std::map<std::uintptr_t, std::size_t> r;
    return r;
  }

 private:
  char* base_ = nullptr;
  std::size_t size_ = 0;
};

}  // namespace

TensorFile map_safetensors(const std::string& path) {
  OpenedFile file;
  open_checkpoint(path, &file);
  SafetensorsHeader& h = file.header;
  struct stat st;
  if (::fstat(file.f.fd, &st) != 0) throw CheckpointError(path + ": cannot stat: " + errno_text());
  TensorFile out;
  out.metadata = std::move(h.metadata);
  std::shared_ptr<Mapping> mapping;
  if (st.st_size > 0) {
    mapping = std::make_shared<Mapping>(file.f.fd, static_cast<std::size_t>(st.st_size), path);
  }
  for (const TensorEntry& e : h.tensors) {
    const auto options = at::TensorOptions().dtype(to_scalar_type(e.dtype));
    const uint64_t nbytes = e.end - e.begin, offset = h.data_offset + e.begin;
    if (nbytes == 0 || offset % dtype_size(e.dtype) != 0) {  // nothing to map, or unaligned
      at::Tensor t = at::empty(e.shape, options);
      if (nbytes > 0) {
        read_at(file.f.fd, offset, t.data_ptr(), nbytes, path, "tensor " + quoted(e.name));
      }
      out.tensors.emplace(e.name, std::move(t));
      continue;
    }
    out.tensors.emplace(e.name, at::from_blob(
                                    mapping->base() + offset, e.shape,
                                    [mapping](void*) mutable { mapping.reset(); }, options));
  }
  return out;
}

void release_mapped(const at::Tensor& view) {
  if (!view.defined() || view.nbytes() == 0) return;
  const auto begin = reinterpret_cast<std::uintptr_t>(view.data_ptr());
  const std::uintptr_t end = begin + view.nbytes();
  std::lock_guard<std::mutex> lock(Mapping::registry_mutex());
  const auto& registry = Mapping::registry();
  auto it = registry.upper_bound(begin);
  if (it == registry.begin()) return;
  --it;                                      // the last mapping starting at or before the view
  if (end > it->first + it->second) return;  // not inside it
  const auto page = static_cast<std::uintptr_t>(::sysconf(_SC_PAGESIZE));
  // Whole pages, clipped to the mapping (a shared edge page is read again if needed).
  const std::uintptr_t from = std::max(begin / page * page, it->first);
  const std::uintptr_t to = std::min((end + page - 1) / page * page, it->first + it->second);
  ::madvise(reinterpret_cast<void*>(from), to - from, MADV_DONTNEED);
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

  try {
    AtomicFile file(path);
    uint8_t len[8];
    encode_header_length(header.size(), len);
    file.write(len, 8);
    file.write(header);
    for (const Item* it : order) {
      const uint64_t nbytes = static_cast<uint64_t>(it->t.numel()) * dtype_size(it->dtype);
      if (nbytes > 0) file.write(it->t.data_ptr(), static_cast<std::size_t>(nbytes));
    }
    file.commit();
  } catch (const AtomicWriteError& e) {
    throw CheckpointError(e.what());
  }
}

}  // namespace long3r
