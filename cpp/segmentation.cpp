// Euclidean clustering and supporting-plane fit (pcl_segmentation, pcl_sample_consensus).
#include <pcl/segmentation/extract_clusters.h>
#include <pcl/sample_consensus/ransac.h>
#include <pcl/sample_consensus/sac_model_plane.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <numeric>
#include <thread>

#include "binpick-pcl/src/ffi.rs.h"
#include "internal.h"

// The classes this module shares with the reference pipeline, compiled here once (internal.h).
BINPICK_SEGMENTATION_TEMPLATES(BINPICK_INSTANTIATE_TEMPLATE)

namespace binpick {

// pcl::EuclideanClusterExtraction (thesis 3.4.1.3) on an uploaded cloud, reusing its kd-tree
// (or its neighbourhood cache, when the upload built one that covers the tolerance).
// Clusters outside [min_size, max_size] are dropped by PCL, not split. Output: indices of all
// clusters concatenated (each cluster's indices ascending), `offsets[i]..offsets[i+1]` per
// cluster; clusters ordered by their smallest index so the order never depends on ties in
// PCL's size sort.
Clusters euclidean_clusters(const Cloud& cloud, float tolerance, std::uint32_t min_size,
                            std::uint32_t max_size) {
  check_positive(tolerance, "cluster tolerance");
  if (min_size == 0 || min_size > max_size) {
    fail("cluster size range [", min_size, ", ", max_size, "] is empty or starts at 0");
  }
  const auto& c = cloud.impl();
  pcl::EuclideanClusterExtraction<pcl::PointXYZ> ec;
  ec.setClusterTolerance(tolerance);
  ec.setMinClusterSize(static_cast<pcl::uindex_t>(min_size));
  ec.setMaxClusterSize(static_cast<pcl::uindex_t>(max_size));
  // PCL's clustering re-points its search method at the input, which rebuilds a kd-tree: it
  // gets a tree of its own so the shared cloud is never modified (the cache is not rebuilt).
  auto search = radius_search_method(c, tolerance);
  if (search == c.tree) search = make_tree(c.points);
  ec.setSearchMethod(search);
  ec.setInputCloud(c.points);
  std::vector<pcl::PointIndices> found;
  ec.extract(found);
  for (auto& f : found) std::sort(f.indices.begin(), f.indices.end());
  std::sort(found.begin(), found.end(), [](const pcl::PointIndices& a, const pcl::PointIndices& b) {
    return a.indices.front() < b.indices.front();
  });
  Clusters out;
  out.offsets.push_back(0);
  for (const auto& f : found) {
    for (auto i : f.indices) out.indices.push_back(static_cast<std::uint32_t>(i));
    out.offsets.push_back(static_cast<std::uint32_t>(out.indices.size()));
  }
  return out;
}

namespace {

// Runs one job per shard, shard 0 on the calling thread and the others on helper threads
// that live as long as the runner (one plane fit) and wait for work by spinning: RANSAC asks
// for a count every few microseconds, far too often to start threads or sleep between.
class ShardRunner {
 public:
  explicit ShardRunner(int shards) : shards_(shards) {
    for (int s = 1; s < shards; ++s) helpers_.emplace_back([this, s] { serve(s); });
  }
  ~ShardRunner() {
    stop_.store(true, std::memory_order_relaxed);
    generation_.fetch_add(1, std::memory_order_release);
    for (auto& t : helpers_) t.join();
  }
  ShardRunner(const ShardRunner&) = delete;
  ShardRunner& operator=(const ShardRunner&) = delete;

  // Calls job(s) for every shard s and returns when all have returned. Not reentrant.
  void run(const std::function<void(int)>& job) {
    job_ = &job;
    done_.store(0, std::memory_order_relaxed);
    generation_.fetch_add(1, std::memory_order_release);
    job(0);
    while (done_.load(std::memory_order_acquire) < shards_ - 1) std::this_thread::yield();
  }

 private:
  void serve(int shard) {
    std::uint64_t seen = 0;
    for (;;) {
      std::uint64_t g;
      while ((g = generation_.load(std::memory_order_acquire)) == seen) std::this_thread::yield();
      seen = g;
      if (stop_.load(std::memory_order_relaxed)) return;
      (*job_)(shard);
      done_.fetch_add(1, std::memory_order_release);
    }
  }

  const int shards_;
  const std::function<void(int)>* job_ = nullptr;
  std::atomic<std::uint64_t> generation_{0};
  std::atomic<int> done_{0};
  std::atomic<bool> stop_{false};
  std::vector<std::thread> helpers_;
};

// pcl::SampleConsensusModelPlane whose inlier count, RANSAC's inner loop and most of a plane
// fit's time, is split over threads: each thread counts one contiguous shard of the points,
// and the integer counts add up to the whole model's count whatever the split. Everything
// else (samples, model, refinement, final inliers) is PCL's own.
//
// The count is PCL 1.13's `countWithinDistanceStandard` (the path Debian's build takes: no
// SSE4.1) with the same float arithmetic, over each shard's points copied once into
// contiguous arrays. PCL's loop gathers every point through its index into a stack vector
// and reads it back as one 16-byte load, a store-forwarding stall per point: about 9 ns a
// point, 200 times per fit (measured on the 20-31 k points left after a belt's plane).
// Bridge tests: `split_plane_count_is_pcls_count_to_the_last_point` (the counts) and
// `plane_fit_is_the_same_on_any_number_of_threads` (whole fits against SACSegmentation).
class ShardedPlaneModel : public pcl::SampleConsensusModelPlane<pcl::PointXYZ> {
 public:
  using Plane = pcl::SampleConsensusModelPlane<pcl::PointXYZ>;

  ShardedPlaneModel(const PointCloudXYZ::ConstPtr& cloud, const pcl::Indices& indices,
                    int threads)
      : Plane(cloud, indices, /*random=*/false), runner_(threads), counts_(threads),
        shards_(threads) {
    const std::size_t n = indices.size();
    for (int s = 0; s < threads; ++s) {
      const std::size_t begin = n * s / threads;
      const std::size_t end = n * (s + 1) / threads;
      Shard& shard = shards_[s];
      shard.begin = begin;
      shard.x.reserve(end - begin);
      shard.y.reserve(end - begin);
      shard.z.reserve(end - begin);
      for (std::size_t i = begin; i < end; ++i) {
        const auto& p = (*cloud)[indices[i]];
        shard.x.push_back(p.x);
        shard.y.push_back(p.y);
        shard.z.push_back(p.z);
      }
    }
  }

  // Called inside PCL's RANSAC loop, an OpenMP region that an exception must not leave: once
  // the caller asks to stop, every count is 0 (RANSAC then runs out its iterations at once)
  // and `segment_plane` throws after it returns.
  std::size_t countWithinDistance(const Eigen::VectorXf& coefficients,
                                  const double threshold) const override {
    if (interrupted() || interrupt_requested()) {
      interrupted_.store(true, std::memory_order_relaxed);
      return 0;
    }
    // As PCL's countWithinDistance: an invalid model counts nothing.
    if (!isModelValid(coefficients)) return 0;
    const float a = coefficients[0], b = coefficients[1], c = coefficients[2],
                d = coefficients[3];
    runner_.run([&](int s) { counts_[s] = shards_[s].count_within(a, b, c, d, threshold); });
    return std::accumulate(counts_.begin(), counts_.end(), std::size_t{0});
  }

  // PCL's selectWithinDistance (the inliers RANSAC keeps, and the final ones after the
  // refinement) with count_within's arithmetic, each shard selecting its points in parallel and
  // the selections joined in shard order: the same indices in the same order and the same
  // error_sqr_dists_ as PCL's loop, without its per-point stall (bridge test
  // `split_plane_count_is_pcls_count_to_the_last_point`). An invalid model is PCL's own case.
  void selectWithinDistance(const Eigen::VectorXf& coefficients, const double threshold,
                            pcl::Indices& inliers) override {
    if (!isModelValid(coefficients)) {
      Plane::selectWithinDistance(coefficients, threshold, inliers);
      return;
    }
    const float a = coefficients[0], b = coefficients[1], c = coefficients[2],
                d = coefficients[3];
    std::vector<std::vector<std::uint32_t>> at(shards_.size());
    std::vector<std::vector<float>> distance(shards_.size());
    runner_.run([&](int s) { shards_[s].select_within(a, b, c, d, threshold, at[s], distance[s]); });
    inliers.clear();
    error_sqr_dists_.clear();
    for (std::size_t s = 0; s < shards_.size(); ++s) {
      for (std::size_t k = 0; k < at[s].size(); ++k) {
        inliers.push_back((*indices_)[shards_[s].begin + at[s][k]]);
        error_sqr_dists_.push_back(static_cast<double>(distance[s][k]));
      }
    }
  }

 public:
  // Whether the caller asked to stop during the fit (its answer is then meaningless).
  bool interrupted() const { return interrupted_.load(std::memory_order_relaxed); }

 private:
  struct Shard {
    std::size_t begin = 0;  // position of the shard's first point in the model's indices
    std::vector<float> x, y, z;

    // Points with |a x + b y + c z + d| < threshold, each distance rounded as PCL's
    // Eigen dot (SSE2) rounds it: lanes a x, b y, c z, d * 1, summed (a x + c z) + (b y + d)
    // in float, then compared in double. The bridge is compiled without FMA contraction.
    std::size_t count_within(float a, float b, float c, float d, double threshold) const {
      std::size_t n = 0;
      const std::size_t size = x.size();
      for (std::size_t i = 0; i < size; ++i) {
        const float distance = (a * x[i] + c * z[i]) + (b * y[i] + d);
        n += static_cast<double>(std::fabs(distance)) < threshold;
      }
      return n;
    }

    // The points count_within counts: their positions in the shard and |distance|, in order.
    void select_within(float a, float b, float c, float d, double threshold,
                       std::vector<std::uint32_t>& at, std::vector<float>& distance) const {
      const std::size_t size = x.size();
      for (std::size_t i = 0; i < size; ++i) {
        const float e = std::fabs((a * x[i] + c * z[i]) + (b * y[i] + d));
        if (static_cast<double>(e) < threshold) {
          at.push_back(static_cast<std::uint32_t>(i));
          distance.push_back(e);
        }
      }
    }
  };
  mutable std::atomic<bool> interrupted_{false};
  mutable ShardRunner runner_;
  mutable std::vector<std::size_t> counts_;
  std::vector<Shard> shards_;
};

// Below this many points a plane fit is not worth splitting over threads (one shard counts).
constexpr std::size_t kMinPointsPerShard = 8000;

}  // namespace

// For each plane (a, b, c, d), by PCL's SampleConsensusModelPlane and by the split model over
// two shards: the inlier counts, then the sizes of the selections (selectWithinDistance), the
// split one only when its indices and distances are PCL's exactly (else u64 max). Four numbers
// per plane, for the bridge test that the two agree.
rust::Vec<std::uint64_t> plane_inlier_counts(rust::Slice<const float> xyz,
                                             rust::Slice<const float> planes,
                                             double distance_threshold) {
  if (planes.size() % 4 != 0) {
    fail("plane_inlier_counts: ", planes.size(), " plane values, not 4 per plane");
  }
  // PCL's plane model as it is, with its selection's distances readable.
  struct PclPlane : pcl::SampleConsensusModelPlane<pcl::PointXYZ> {
    using SampleConsensusModelPlane::SampleConsensusModelPlane;
    const std::vector<double>& distances() const { return error_sqr_dists_; }
  };
  struct SplitPlane : ShardedPlaneModel {
    using ShardedPlaneModel::ShardedPlaneModel;
    const std::vector<double>& distances() const { return error_sqr_dists_; }
  };
  const auto cloud = to_cloud(xyz, "plane_inlier_counts");
  pcl::Indices all(cloud->size());
  std::iota(all.begin(), all.end(), 0);
  PclPlane pcl_model(cloud, all, /*random=*/false);
  SplitPlane split(cloud, all, 2);
  rust::Vec<std::uint64_t> out;
  for (std::size_t k = 0; k + 4 <= planes.size(); k += 4) {
    Eigen::VectorXf c(4);
    c << planes[k], planes[k + 1], planes[k + 2], planes[k + 3];
    out.push_back(pcl_model.countWithinDistance(c, distance_threshold));
    out.push_back(split.countWithinDistance(c, distance_threshold));
    pcl::Indices by_pcl, by_split;
    pcl_model.selectWithinDistance(c, distance_threshold, by_pcl);
    split.selectWithinDistance(c, distance_threshold, by_split);
    out.push_back(by_pcl.size());
    const bool same = by_split == by_pcl && split.distances() == pcl_model.distances();
    out.push_back(same ? by_split.size() : std::numeric_limits<std::uint64_t>::max());
  }
  return out;
}

namespace {

// A cloud for a plane fit of `max_iterations` RANSAC iterations, or an error naming what is
// wrong.
PointCloudXYZ::Ptr plane_fit_input(rust::Slice<const float> xyz, float distance_threshold,
                                   std::uint32_t max_iterations) {
  check_positive(distance_threshold, "plane distance threshold");
  if (max_iterations == 0) fail("plane fit needs at least one RANSAC iteration");
  if (max_iterations > static_cast<std::uint32_t>(std::numeric_limits<int>::max() / 10)) {
    fail("plane fit: ", max_iterations, " RANSAC iterations is too many");
  }
  auto cloud = to_cloud(xyz, "segment_plane");
  if (cloud->size() < 3) fail("segment_plane: needs at least 3 points, got ", cloud->size());
  return cloud;
}

PlaneFit plane_fit(const pcl::Indices& inliers, const std::vector<float>& coefficients) {
  PlaneFit out;
  out.found = !inliers.empty() && coefficients.size() == 4;
  if (out.found) {
    for (int i = 0; i < 4; ++i) out.coefficients[i] = coefficients[i];
    for (auto i : inliers) out.inliers.push_back(static_cast<std::uint32_t>(i));
  }
  return out;
}

}  // namespace

// See internal.h.
bool fit_plane_as_sac_segmentation(const pcl::SampleConsensusModelPlane<pcl::PointXYZ>::Ptr& model,
                                   float distance_threshold, std::uint32_t max_iterations,
                                   pcl::Indices& inliers, std::vector<float>& coefficients,
                                   const std::function<void()>& after_search) {
  inliers.clear();
  coefficients.clear();
  pcl::RandomSampleConsensus<pcl::PointXYZ> sac(model, distance_threshold);
  sac.setMaxIterations(static_cast<int>(max_iterations));
  const bool found = sac.computeModel(0);
  if (after_search) after_search();
  if (!found) return false;
  sac.getInliers(inliers);
  Eigen::VectorXf coeff(model->getModelSize()), refined(model->getModelSize());
  sac.getModelCoefficients(coeff);
  model->optimizeModelCoefficients(inliers, coeff, refined);
  coefficients.assign(refined.data(), refined.data() + refined.size());
  model->selectWithinDistance(refined, distance_threshold, inliers);
  return true;
}

// The plane fit of pcl::SACSegmentation (RANSAC plane, optimised coefficients; deterministic:
// PCL seeds its generator with 12345), with the inlier counts split over `threads` (0 = all
// cores) on large clouds and counted without PCL's per-point stall (`ShardedPlaneModel`): same
// draws, same counts, same plane as `segment_plane_pcl` (bridge test
// `plane_fit_is_the_same_on_any_number_of_threads`). `found` is false when PCL finds no plane.
PlaneFit segment_plane(rust::Slice<const float> xyz, float distance_threshold,
                       std::uint32_t max_iterations, std::uint32_t threads) {
  const auto cloud = plane_fit_input(xyz, distance_threshold, max_iterations);
  const int shards = static_cast<int>(std::clamp<std::size_t>(
      cloud->size() / kMinPointsPerShard, 1,
      threads == 0 ? std::max(1u, std::thread::hardware_concurrency()) : threads));
  pcl::Indices all(cloud->size());
  std::iota(all.begin(), all.end(), 0);
  auto model = std::make_shared<ShardedPlaneModel>(cloud, all, shards);
  pcl::Indices inliers;
  std::vector<float> coefficients;
  fit_plane_as_sac_segmentation(model, distance_threshold, max_iterations, inliers, coefficients,
                                [&] {
                                  if (model->interrupted()) throw_interrupted("support plane fit");
                                });
  return plane_fit(inliers, coefficients);
}

bool fit_plane_pcl(const PointCloudXYZ::Ptr& cloud, float distance_threshold,
                   std::uint32_t max_iterations, pcl::Indices& inliers,
                   std::vector<float>& coefficients) {
  pcl::Indices all(cloud->size());
  std::iota(all.begin(), all.end(), 0);
  auto model =
      std::make_shared<pcl::SampleConsensusModelPlane<pcl::PointXYZ>>(cloud, all, /*random=*/false);
  return fit_plane_as_sac_segmentation(model, distance_threshold, max_iterations, inliers,
                                       coefficients);
}

// The same fit with PCL's own SampleConsensusModelPlane on one thread: the bridge tests'
// reference.
PlaneFit segment_plane_pcl(rust::Slice<const float> xyz, float distance_threshold,
                           std::uint32_t max_iterations) {
  const auto cloud = plane_fit_input(xyz, distance_threshold, max_iterations);
  pcl::Indices inliers;
  std::vector<float> coefficients;
  fit_plane_pcl(cloud, distance_threshold, max_iterations, inliers, coefficients);
  return plane_fit(inliers, coefficients);
}

}  // namespace binpick
