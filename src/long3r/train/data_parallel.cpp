// Data-parallel training on c10d; see include/long3r/train/data_parallel.hpp.
#include "long3r/train/data_parallel.hpp"

#include <ATen/ATen.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include "long3r/config/config_fields.hpp"
#include "long3r/io/fnv1a.hpp"

#ifdef LONG3R_WITH_C10D
#include <torch/csrc/distributed/c10d/PrefixStore.hpp>
#include <torch/csrc/distributed/c10d/ProcessGroup.hpp>
#include <torch/csrc/distributed/c10d/TCPStore.hpp>
#ifdef USE_C10D_GLOO
#include <torch/csrc/distributed/c10d/ProcessGroupGloo.hpp>
#endif
#ifdef USE_C10D_NCCL
#include <torch/csrc/distributed/c10d/ProcessGroupNCCL.hpp>
#endif
#endif

namespace long3r {

namespace {

// A whole non-negative integer variable, or ConfigError naming it.
int env_int(const std::function<const char*(const char*)>& lookup, const char* name, int lo,
            int hi) {
  const char* v = lookup(name);
  const std::string text = v ? v : "";
  std::size_t used = 0;
  long value = -1;
  try {
    value = std::stol(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (text.empty() || used != text.size() || value < lo || value > hi) {
    throw ConfigError("distributed training: " + std::string(name) + "=\"" + text +
                      "\" is not a whole number in [" + std::to_string(lo) + ", " +
                      std::to_string(hi) + "]");
  }
  return static_cast<int>(value);
}

bool env_set(const std::function<const char*(const char*)>& lookup, const char* name) {
  const char* v = lookup(name);
  return v != nullptr && *v != '\0';
}

}  // namespace

std::string DistributedEnv::describe() const {
  return "rank " + std::to_string(rank) + " of " + std::to_string(world_size);
}

DistributedEnv distributed_env_from(const std::function<const char*(const char*)>& lookup) {
  DistributedEnv env;
  constexpr int kMaxRanks = 1 << 20;
  const char *rank_var = nullptr, *world_var = nullptr, *local_var = nullptr;
  if (env_set(lookup, "RANK") || env_set(lookup, "WORLD_SIZE")) {
    rank_var = "RANK";
    world_var = "WORLD_SIZE";
    local_var = "LOCAL_RANK";
    env.launcher = env_set(lookup, "TORCHELASTIC_RUN_ID") ? "torchrun" : "environment";
  } else if (env_set(lookup, "SLURM_PROCID") && env_set(lookup, "SLURM_NTASKS")) {
    rank_var = "SLURM_PROCID";
    world_var = "SLURM_NTASKS";
    local_var = "SLURM_LOCALID";
    env.launcher = "srun";
  } else {
    return env;  // one process
  }
  env.world_size = env_int(lookup, world_var, 1, kMaxRanks);
  env.rank = env_int(lookup, rank_var, 0, env.world_size - 1);
  env.local_rank = env_set(lookup, local_var) ? env_int(lookup, local_var, 0, env.rank) : 0;
  if (!env.distributed()) return env;
  if (!env_set(lookup, "MASTER_ADDR") || !env_set(lookup, "MASTER_PORT")) {
    throw ConfigError(
        "distributed training (" + env.launcher + ", " + env.describe() +
        "): MASTER_ADDR and MASTER_PORT must name rank 0's host and a free port" +
        (env.launcher == "srun"
             ? " (export them in the batch script, e.g. MASTER_ADDR=$(scontrol show hostnames "
               "\"$SLURM_JOB_NODELIST\" | head -n 1))"
             : std::string()));
  }
  env.master_addr = lookup("MASTER_ADDR");
  env.master_port = env_int(lookup, "MASTER_PORT", 1, 65535);
  const char* agent = lookup("TORCHELASTIC_USE_AGENT_STORE");
  env.agent_store = agent != nullptr && std::string(agent) == "True";
  if (env_set(lookup, "TORCHELASTIC_RESTART_COUNT")) {
    env.restart_count = env_int(lookup, "TORCHELASTIC_RESTART_COUNT", 0, kMaxRanks);
  }
  return env;
}

DistributedEnv distributed_env() {
  return distributed_env_from([](const char* name) -> const char* { return std::getenv(name); });
}

void DataParallelConfig::validate() const {
  if (backend != "auto" && backend != "gloo" && backend != "nccl") {
    throw ConfigError("data parallel: backend \"" + backend +
                      "\" is not one of \"auto\", \"gloo\", \"nccl\"");
  }
  if (!(timeout_s > 0.0) || !std::isfinite(timeout_s)) {
    throw ConfigError("data parallel: timeout_s must be > 0 seconds");
  }
  if (!(bucket_mib > 0.0) || !std::isfinite(bucket_mib)) {
    throw ConfigError("data parallel: bucket_mib must be > 0");
  }
}

bool data_parallel_backend_available(const std::string& backend) {
#if defined(LONG3R_WITH_C10D) && defined(USE_C10D_GLOO)
  if (backend == "gloo") return true;
#endif
#if defined(LONG3R_WITH_C10D) && defined(USE_C10D_NCCL)
  if (backend == "nccl") return true;
#endif
  (void)backend;
  return false;
}

uint64_t tensors_fingerprint(const std::vector<at::Tensor>& tensors) {
  Fnv1a f;
  for (const at::Tensor& t : tensors) {
    const at::Tensor c = t.detach().to(at::kCPU).contiguous();
    f.add(c.data_ptr(), static_cast<std::size_t>(c.numel() * c.element_size()));
  }
  return f.h;
}

// ------------------------------------------------------------------ group

struct DataParallel::Impl {
  DistributedEnv env;
  DataParallelConfig config;
  std::string backend;
#ifdef LONG3R_WITH_C10D
  c10::intrusive_ptr<c10d::ProcessGroup> group;
  using WorkPtr = decltype(group->barrier());
#endif

  // Gradient buckets: params[i] lives in bucket slot[i] at offset[i].
  struct Bucket {
    at::Tensor flat;
    std::vector<std::size_t> members;  // parameter indices
    int64_t expected = 0;              // members that require a gradient this step
    int64_t arrived = 0;
    bool launched = false;
#ifdef LONG3R_WITH_C10D
    WorkPtr work;
#endif
  };
  std::vector<at::Tensor> params;
  std::vector<unsigned> hooks;
  std::vector<std::size_t> bucket_of;
  std::vector<int64_t> offset_of;
  std::vector<bool> filled;
  std::vector<Bucket> buckets;
  std::size_t next_launch = 0;
  bool in_backward = false;
  std::mutex mutex;

  void on_grad(std::size_t i, const at::Tensor& grad);
  void launch_ready();  // under mutex
  void launch(Bucket& b);

  [[noreturn]] void fail(const std::string& what, const std::exception& e) const {
    throw std::runtime_error("data parallel (" + backend + "): " + what + " failed: " + e.what() +
                             " (another rank ended or stopped answering)");
  }
};

DataParallel::DataParallel(const DistributedEnv& env, const DataParallelConfig& config,
                           const at::Device& device)
    : impl_(std::make_unique<Impl>()) {
  config.validate();
  impl_->env = env;
  impl_->config = config;
  std::string backend = config.backend;
  if (backend == "auto") {
    backend = device.is_cuda() && data_parallel_backend_available("nccl") ? "nccl" : "gloo";
  }
  impl_->backend = backend;
  if (!data_parallel_backend_available(backend)) {
    throw ConfigError("distributed training (" + env.describe() + "): this build has no c10d " +
                      backend + " backend" +
                      (backend == "gloo" ? " (it needs libtorch's c10d and the Gloo headers, "
                                           "Debian's libgloo-dev, when it is built)"
                                         : " (it needs a CUDA libtorch with NCCL)"));
  }
  if (backend == "nccl" && !device.is_cuda()) {
    throw ConfigError("distributed training: the nccl backend needs a CUDA device, not " +
                      device.str());
  }
#ifdef LONG3R_WITH_C10D
  const auto timeout = std::chrono::milliseconds(static_cast<int64_t>(config.timeout_s * 1000.0));
  c10d::TCPStoreOptions store_options;
  store_options.port = static_cast<std::uint16_t>(env.master_port);
  store_options.isServer = env.rank == 0 && !env.agent_store;
  if (store_options.isServer) store_options.numWorkers = static_cast<std::size_t>(env.world_size);
  store_options.waitWorkers = false;  // the group's rendezvous below waits for every rank
  store_options.timeout = timeout;
  try {
    auto tcp = c10::make_intrusive<c10d::TCPStore>(env.master_addr, store_options);
    // Keys of their own, per torchrun restart, beside those of torchrun's agent.
    auto store = c10::make_intrusive<c10d::PrefixStore>(
        "long3r_train/" + std::to_string(env.restart_count), tcp);
#ifdef USE_C10D_GLOO
    if (backend == "gloo") {
      auto options = c10d::ProcessGroupGloo::Options::create(timeout);
      // GLOO_SOCKET_IFNAME picks the network interface, as for torch's own
      // init_process_group; else the one this host's name resolves to.
      const char* ifname = std::getenv("GLOO_SOCKET_IFNAME");
      options->devices.push_back(ifname && *ifname
                                     ? c10d::ProcessGroupGloo::createDeviceForInterface(ifname)
                                     : c10d::ProcessGroupGloo::createDefaultDevice());
      impl_->group =
          c10::make_intrusive<c10d::ProcessGroupGloo>(store, env.rank, env.world_size, options);
    }
#endif
#ifdef USE_C10D_NCCL
    if (backend == "nccl") {
      auto options = c10d::ProcessGroupNCCL::Options::create();
      options->timeout = timeout;
      impl_->group =
          c10::make_intrusive<c10d::ProcessGroupNCCL>(store, env.rank, env.world_size, options);
    }
#endif
  } catch (const std::exception& e) {
    throw std::runtime_error("data parallel (" + backend + "): joining the group at " +
                             env.master_addr + ":" + std::to_string(env.master_port) +
                             " failed: " + e.what());
  }
  barrier();  // every rank is there before the first step
#else
  (void)device;
#endif
}

DataParallel::~DataParallel() {
  for (std::size_t i = 0; i < impl_->hooks.size(); ++i) {
    impl_->params[i].remove_hook(impl_->hooks[i]);
  }
}

int DataParallel::rank() const { return impl_->env.rank; }
int DataParallel::world_size() const { return impl_->env.world_size; }
const std::string& DataParallel::backend() const { return impl_->backend; }

#ifdef LONG3R_WITH_C10D

void DataParallel::broadcast(const std::vector<at::Tensor>& tensors) {
  try {
    for (const at::Tensor& t : tensors) {
      std::vector<at::Tensor> one{t};
      impl_->group->broadcast(one)->wait();
    }
  } catch (const std::exception& e) {
    impl_->fail("broadcast", e);
  }
}

void DataParallel::sum(const at::Tensor& tensor) {
  try {
    std::vector<at::Tensor> one{tensor};
    impl_->group->allreduce(one)->wait();
  } catch (const std::exception& e) {
    impl_->fail("all-reduce", e);
  }
}

void DataParallel::barrier() {
  try {
    impl_->group->barrier()->wait();
  } catch (const std::exception& e) {
    impl_->fail("barrier", e);
  }
}

void DataParallel::Impl::launch(Bucket& b) {
  std::vector<at::Tensor> one{b.flat};
  try {
    b.work = group->allreduce(one);
  } catch (const std::exception& e) {
    fail("gradient all-reduce", e);
  }
  b.launched = true;
}

void DataParallel::finish_backward() {
  Impl& m = *impl_;
  std::lock_guard<std::mutex> lock(m.mutex);
  for (std::size_t k = m.next_launch; k < m.buckets.size(); ++k) {
    Impl::Bucket& b = m.buckets[k];
    if (b.expected == 0 || b.launched) continue;
    // Parameters without a gradient this step count as zeros.
    for (const std::size_t i : b.members) {
      if (!m.filled[i]) b.flat.narrow(0, m.offset_of[i], m.params[i].numel()).zero_();
    }
    m.launch(b);
  }
  m.next_launch = m.buckets.size();
  const double inv = 1.0 / static_cast<double>(m.env.world_size);
  for (Impl::Bucket& b : m.buckets) {
    if (!b.launched) continue;
    try {
      b.work->wait();
    } catch (const std::exception& e) {
      m.fail("gradient all-reduce", e);
    }
    b.work.reset();
    b.flat.mul_(inv);
    for (const std::size_t i : b.members) {
      at::Tensor& p = m.params[i];
      if (!m.filled[i] || !p.grad().defined()) continue;
      p.mutable_grad().copy_(b.flat.narrow(0, m.offset_of[i], p.numel()).view(p.sizes()));
    }
  }
  m.in_backward = false;
}

#else

namespace {
// Without c10d the constructor refuses every backend, so no group exists to
// call these on.
[[noreturn]] void no_group() { throw std::logic_error("DataParallel: built without c10d"); }
}  // namespace
void DataParallel::broadcast(const std::vector<at::Tensor>&) { no_group(); }
void DataParallel::sum(const at::Tensor&) { no_group(); }
void DataParallel::barrier() { no_group(); }
void DataParallel::Impl::launch(Bucket&) { no_group(); }
void DataParallel::finish_backward() { no_group(); }

#endif

bool DataParallel::any(bool local) {
  const at::Tensor t = at::full({1}, local ? 1.0 : 0.0, at::kDouble);
  sum(t);
  return t.item<double>() > 0.0;
}

std::vector<int64_t> DataParallel::gather(int64_t local) {
  // A sum in which each rank fills its own slot.
  const at::Tensor t = at::zeros({world_size()}, at::kLong);
  t[rank()] = local;
  sum(t);
  return std::vector<int64_t>(t.data_ptr<int64_t>(), t.data_ptr<int64_t>() + t.numel());
}

void DataParallel::attach(const std::vector<at::Tensor>& params) {
  Impl& m = *impl_;
  if (!m.params.empty()) throw std::logic_error("DataParallel::attach: already attached");
  const int64_t cap = std::max<int64_t>(
      1, static_cast<int64_t>(m.config.bucket_mib * 1024.0 * 1024.0 / sizeof(float)));
  m.params = params;
  m.bucket_of.assign(params.size(), 0);
  m.offset_of.assign(params.size(), 0);
  m.filled.assign(params.size(), false);
  // Buckets in reverse order of the parameters: roughly the order in which
  // the backward pass finishes their gradients.
  int64_t used = 0;
  for (std::size_t k = params.size(); k-- > 0;) {
    const at::Tensor& p = params[k];
    if (p.scalar_type() != at::kFloat || p.device() != params[0].device()) {
      throw std::invalid_argument(
          "DataParallel::attach: every parameter must be float32 on one device");
    }
    if (m.buckets.empty() || (used > 0 && used + p.numel() > cap)) {
      m.buckets.emplace_back();
      used = 0;
    }
    m.buckets.back().members.push_back(k);
    m.bucket_of[k] = m.buckets.size() - 1;
    m.offset_of[k] = used;
    used += p.numel();
  }
  for (Impl::Bucket& b : m.buckets) {
    int64_t n = 0;
    for (const std::size_t i : b.members) n += params[i].numel();
    b.flat = at::zeros({n}, params[0].options().requires_grad(false));
  }
  Impl* impl = impl_.get();
  for (std::size_t i = 0; i < params.size(); ++i) {
    m.hooks.push_back(
        m.params[i].register_hook([impl, i](const at::Tensor& grad) { impl->on_grad(i, grad); }));
  }
}

void DataParallel::begin_backward() {
  Impl& m = *impl_;
  std::lock_guard<std::mutex> lock(m.mutex);
  std::fill(m.filled.begin(), m.filled.end(), false);
  for (Impl::Bucket& b : m.buckets) {
    b.expected = 0;
    b.arrived = 0;
    b.launched = false;
    for (const std::size_t i : b.members) b.expected += m.params[i].requires_grad() ? 1 : 0;
  }
  m.next_launch = 0;
  m.in_backward = true;
  m.launch_ready();  // skips the leading buckets with nothing to reduce
}

void DataParallel::Impl::on_grad(std::size_t i, const at::Tensor& grad) {
  std::lock_guard<std::mutex> lock(mutex);
  if (!in_backward) return;  // a backward pass outside a training step
  Bucket& b = buckets[bucket_of[i]];
  if (b.launched) {
    throw std::logic_error("DataParallel: a gradient arrived for an all-reduce already started");
  }
  at::Tensor slot = b.flat.narrow(0, offset_of[i], params[i].numel()).view(params[i].sizes());
  if (filled[i]) {
    slot.add_(grad.detach());
  } else {
    slot.copy_(grad.detach());
    filled[i] = true;
    ++b.arrived;
  }
  launch_ready();
}

void DataParallel::Impl::launch_ready() {
  while (next_launch < buckets.size()) {
    Bucket& b = buckets[next_launch];
    if (b.expected > 0) {
      if (b.arrived < b.expected) return;
      launch(b);
    }
    ++next_launch;
  }
}

}  // namespace long3r
