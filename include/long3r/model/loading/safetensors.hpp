// safetensors checkpoints: validated reading and atomic writing.
//
// The header parser is torch-free (see safetensors_header.hpp); this file adds
// the tensor side. Every error is a long3r::CheckpointError whose message names
// the file and, where there is one, the tensor.
#pragma once

#include <ATen/core/Tensor.h>

#include <map>
#include <string>

#include "long3r/io/safetensors_header.hpp"

namespace long3r {

// All tensors of a file (CPU, contiguous, in their stored dtype: F32, F16,
// BF16 or I64) and its string metadata.
struct TensorFile {
  std::map<std::string, at::Tensor> tensors;
  std::map<std::string, std::string> metadata;
};

// Reads and validates a whole file. Throws CheckpointError on any problem;
// what is not a regular readable file (a directory, a FIFO, a device) is
// refused before anything is read.
TensorFile load_safetensors(const std::string& path);

// A file's tensors as views of a private mapping of it, validated as
// load_safetensors validates: a page is read when first touched, and
// release_mapped() gives a view's pages back once they are copied elsewhere,
// so that loading a model holds about one tensor of the file at a time beside
// the model (a 2.6 GB checkpoint needs no second 2.6 GB). The views are
// copy-on-write (writing to one changes neither the file nor the other
// views); the mapping lives while any view does. A tensor whose data is not
// aligned to its element size is read into memory of its own instead.
TensorFile map_safetensors(const std::string& path);
// Drops the resident pages of a view made by map_safetensors() (they are read
// again from the file if touched); does nothing for any other tensor.
void release_mapped(const at::Tensor& view);

// The string metadata only (the header is read and validated, the tensors are
// not). Throws CheckpointError as load_safetensors does.
std::map<std::string, std::string> read_safetensors_metadata(const std::string& path);

// Writes tensors (any device; stored as their dtype, C-contiguous) and metadata
// to path atomically: a temporary file beside it, then rename.
void save_safetensors(const std::string& path, const std::map<std::string, at::Tensor>& tensors,
                      const std::map<std::string, std::string>& metadata = {});

}  // namespace long3r
