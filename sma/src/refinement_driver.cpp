#include "penumbra/sma/refinement_driver.h"

#include <mutex>

#include "penumbra/common/duration.h"

namespace penumbra::sma {

RefinementDriver::RefinementDriver(RefinementParams params, uint64_t maxSamplesPerView)
    : params_(params), maxSamplesPerView_(maxSamplesPerView), refiner_(std::make_shared<Refiner>(params)) {}

void RefinementDriver::Restart() {
  RestartSameView();
  requestedThisView_ = 0;
  ++viewSerial_;
}

void RefinementDriver::RestartSameView() {
  refiner_ = std::make_shared<Refiner>(params_);
  done_ = false;
  pending_.clear();
  total_ = doneCount_ = 0;
}

RefinementDriver::Start RefinementDriver::StartStep(bool stage1Done) {
  if (!Enabled() || running_ || done_ || !stage1Done) return Start::kNothing;
  // The samples one client's refinement may create for one view are capped
  // (fuzzed options once grew the SMA by 17 MiB/s, for good).
  if (Requested() >= maxSamplesPerView_) {
    done_ = true;
    return Start::kCapReached;
  }
  running_ = true;
  stepSerial_ = viewSerial_;
  return Start::kStep;
}

RefinementStep RefinementDriver::RunStep(std::shared_ptr<Refiner> refiner, const HitBuffer& hits,
                                         const VisibleSet& visible, bool outstanding,
                                         const RefinementStepContext& context) {
  RefinementStep step;
  std::vector<NodeId> chosen;
  uint64_t generation = 0;
  {
    std::shared_lock lock(context.stateMutex);
    generation = context.hierarchy.StructureGeneration();
    if (visible.structureGeneration != generation) {
      step.staleMapping = true;
    } else {
      chosen = refiner->Select(context.hierarchy, context.cache, hits, visible, context.toneMapping, outstanding);
    }
  }
  if (!chosen.empty()) {
    std::unique_lock lock(context.stateMutex);
    const auto locked = std::chrono::steady_clock::now();
    // A collection between the choice and now may have freed or reused the
    // chosen ids: choose again from a fresh mapping.
    if (context.hierarchy.StructureGeneration() != generation) {
      step.staleMapping = true;
      chosen.clear();
    }
    const RefineOptions options = ToRefineOptions(refiner->Params());
    for (NodeId id : chosen) {
      if (context.stop && context.stop->load(std::memory_order_relaxed)) break;  // a step of 10^5 splits takes long
      if (!context.hierarchy.GetNode(id).IsLeaf()) continue;  // split meanwhile, by another client
      RefineResult r = context.hierarchy.Refine(id, options);
      step.created.insert(step.created.end(), r.newVertices.begin(), r.newVertices.end());
      step.remadeVertices += r.remadeVertices;
    }
    context.cache.Reserve(context.hierarchy.VertexCount());
    if (context.request && !step.created.empty()) context.request(step.created);
    step.exclusiveMs = Milliseconds(std::chrono::steady_clock::now() - locked);
  }
  refiner->CountRequested(step.created.size());
  step.chosen = chosen.size();
  step.exhausted = refiner->Exhausted();
  step.refiner = std::move(refiner);
  return step;
}

RefinementDriver::After RefinementDriver::OnStepDone(RefinementStep step, const SampleCache& cache,
                                                     bool remapPending) {
  running_ = false;
  // A step of this view counts against its cap even when a move replaced
  // its Refiner meanwhile; one of an earlier view does not.
  if (stepSerial_ == viewSerial_) requestedThisView_ += step.created.size();
  if (step.refiner != refiner_) return After::kStale;  // the view changed (or was lit anew) meanwhile
  splits_ += step.chosen;
  samples_ += step.created.size();
  // Results may have landed before this step's report: only wait for what
  // is still unshaded.
  size_t waiting = 0;
  for (VertexId v : step.created)
    if (!cache.IsShaded(v) && pending_.insert(v).second) ++waiting;
  total_ += step.created.size();
  doneCount_ += step.created.size() - std::min(step.created.size(), waiting);
  // Bounded batches (the paper's R): the strand takes a turn between steps.
  if (step.chosen > 0) return After::kStepAgain;
  if (step.exhausted) {
    done_ = true;
    return After::kFinished;
  }
  // Nothing to split now. Samples on their way, or a re-map due or running,
  // start the next step when they complete. If all of that happened while
  // this step ran (its trigger found a step running), look again now.
  if (pending_.empty() && !remapPending) return After::kStepNow;
  return After::kWait;
}

bool RefinementDriver::OnSampleArrived(VertexId v) {
  if (pending_.erase(v) == 0) return false;
  ++doneCount_;
  return true;
}

}  // namespace penumbra::sma
