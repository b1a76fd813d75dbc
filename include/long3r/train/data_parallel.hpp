// Data-parallel training on torch's own distributed engine (c10d): one
// process per device, started by a standard launcher (torchrun, SLURM's srun),
// joined into a process group (Gloo on the CPU, NCCL on CUDA where libtorch
// has it); gradients averaged over the ranks in buckets while the backward
// pass still runs, and the few other collectives the trainer needs.
#pragma once

#include <ATen/ATen.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace long3r {

// Where this process sits in the job, as its launcher says it.
struct DistributedEnv {
  int rank = 0;  // 0 .. world_size - 1
  int world_size = 1;
  int local_rank = 0;  // rank on this node: the CUDA device it trains on
  std::string master_addr;
  int master_port = 0;
  // torchrun's agent already serves the store on master_port: every rank
  // joins it as a client (TORCHELASTIC_USE_AGENT_STORE=True).
  bool agent_store = false;
  int restart_count = 0;          // TORCHELASTIC_RESTART_COUNT: a fresh rendezvous per restart
  std::string launcher = "none";  // "torchrun", "srun", "environment" or "none"

  bool distributed() const { return world_size > 1; }
  // "rank R of W" for messages.
  std::string describe() const;
};

// The job from the environment: RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR,
// MASTER_PORT (torchrun, and any launcher that sets them); else SLURM_PROCID,
// SLURM_NTASKS, SLURM_LOCALID with MASTER_ADDR / MASTER_PORT exported by the
// batch script (srun); else one process. A malformed or inconsistent
// variable throws ConfigError naming it. `lookup` stands for std::getenv.
DistributedEnv distributed_env_from(const std::function<const char*(const char*)>& lookup);
DistributedEnv distributed_env();

// How the ranks talk (command-line options of long3r_train).
struct DataParallelConfig {
  // "auto": NCCL for CUDA devices where this libtorch has it, Gloo otherwise;
  // or "gloo" / "nccl".
  std::string backend = "auto";
  // A collective waiting longer than this fails (a rank that hangs, or rank
  // 0 validating for longer): the job ends instead of waiting for ever.
  double timeout_s = 1800.0;
  // Gradients go to the all-reduce in buckets of about this size, as torch's
  // DistributedDataParallel does (bucket_cap_mb 25).
  double bucket_mib = 25.0;

  void validate() const;
};

// Whether this build can join a process group with this backend ("gloo",
// "nccl").
bool data_parallel_backend_available(const std::string& backend);

// One process's membership of the job's process group.
class DataParallel {
 public:
  // Joins the group: blocks until every rank has joined (or the timeout).
  // `device` is where the gradients live (picks the backend for "auto").
  DataParallel(const DistributedEnv& env, const DataParallelConfig& config,
               const at::Device& device);
  ~DataParallel();
  DataParallel(const DataParallel&) = delete;
  DataParallel& operator=(const DataParallel&) = delete;

  int rank() const;
  int world_size() const;
  const std::string& backend() const;

  // Every rank takes rank 0's values, in place.
  void broadcast(const std::vector<at::Tensor>& tensors);
  // Sums over the ranks, in place (blocking).
  void sum(const at::Tensor& tensor);
  // True on every rank when it is true on any.
  bool any(bool local);
  // Each rank's value, in rank order.
  std::vector<int64_t> gather(int64_t local);
  void barrier();

  // Gradient averaging. attach() hooks these parameters once: while the
  // backward pass runs, each gradient is copied into its bucket (buckets in
  // the reverse of this order, the order backward produces them), and a full
  // bucket's all-reduce starts once every earlier bucket has started, so that
  // all ranks issue them in one order. finish_backward() starts the rest (a
  // parameter without a gradient this step counts as zeros), waits, and
  // writes the average into each parameter's .grad. The ranks must run the
  // same graph (the same stage and task): a parameter gets a gradient on all
  // of them or on none.
  void attach(const std::vector<at::Tensor>& params);
  void begin_backward();
  void finish_backward();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// A fingerprint of the tensors' bytes (FNV-1a over each tensor's values as
// stored), equal exactly when they are bit-identical (barring collisions).
uint64_t tensors_fingerprint(const std::vector<at::Tensor>& tensors);

}  // namespace long3r
