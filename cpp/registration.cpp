// Correspondences, RANSAC rejection, SVD and ICP (pcl_registration, thesis 3.4-3.6).
#include <pcl/common/transforms.h>
#include <pcl/registration/correspondence_estimation.h>
#include <pcl/registration/correspondence_rejection_sample_consensus.h>
#include <pcl/registration/icp.h>
#include <pcl/registration/transformation_estimation_svd.h>
#include <pcl/sample_consensus/ransac.h>
#include <pcl/sample_consensus/sac_model_registration.h>

#include <flann/flann.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <unordered_map>

#include "binpick-pcl/src/ffi.rs.h"
#include "internal.h"

// The classes this module shares with the reference pipeline, compiled here once (internal.h).
BINPICK_REGISTRATION_TEMPLATES(BINPICK_INSTANTIATE_TEMPLATE)

namespace binpick {

// The same FLANN index pcl::KdTreeFLANN builds (single kd-tree, 15 points per leaf, exact
// search), kept here so ICP can query all its source points in one pass. The index class
// itself, which flann::Index builds for these parameters, so that queries pass a result set
// of their own.
using KdTree = flann::KDTreeSingleIndex<flann::L2_Simple<float>>;

struct BatchIndex {
  std::vector<float> xyz;
  std::unique_ptr<KdTree> index;
};

// A kd-tree over `xyz` (n points), built as flann::Index builds it. The tree points into
// `xyz`'s buffer: the caller keeps it alive and unmoved as long as the tree.
std::unique_ptr<KdTree> build_kd_tree(std::vector<float>& xyz, std::size_t n) {
  auto tree = std::make_unique<KdTree>(flann::Matrix<float>(xyz.data(), n, 3),
                                       flann::KDTreeSingleIndexParams(15));
  tree->buildIndex();
  return tree;
}

const BatchIndex& batch_index(const Cloud::Impl& cloud) {
  std::call_once(cloud.batch_once, [&cloud] {
    auto b = std::make_shared<BatchIndex>();
    const auto& pts = cloud.points->points;
    b->xyz.reserve(pts.size() * 3);
    for (const auto& p : pts) {
      b->xyz.push_back(p.x);
      b->xyz.push_back(p.y);
      b->xyz.push_back(p.z);
    }
    b->index = build_kd_tree(b->xyz, pts.size());
    cloud.batch = std::move(b);
  });
  return *cloud.batch;
}

namespace {

struct Nearest {
  std::vector<int> index;
  std::vector<float> distance_sqr;
};

// FLANN's radius bound is exclusive and in float: one float step wider than `max_sqr`, then
// PCL's inclusive test in double.
float exclusive_bound(double max_sqr) {
  return std::nextafter(static_cast<float>(max_sqr), std::numeric_limits<float>::infinity());
}

// The k nearest points within a radius as FLANN's KNNRadiusResultSet keeps them, in a
// sorted array instead of its heap: both keep the least k by (distance, index) and refuse a
// point no nearer than the worst kept (or than the radius before k are kept), so the tree
// search prunes alike and finds the same points, given in FLANN's sorted order.
constexpr int MAX_RESULT_POINTS = 8;

class SortedRadiusResultSet : public flann::ResultSet<float> {
 public:
  SortedRadiusResultSet(float radius, int capacity) : radius_(radius), capacity_(capacity) {}

  void clear() { size_ = 0; }
  bool full() const override { return true; }  // as KNNRadiusResultSet
  float worstDist() const override {
    return size_ == capacity_ ? dist_[capacity_ - 1] : radius_;
  }
  void addPoint(float dist, std::size_t index) override {
    if (dist >= worstDist()) return;
    int i = size_ == capacity_ ? capacity_ - 1 : size_++;
    while (i > 0 && (dist < dist_[i - 1] || (dist == dist_[i - 1] && index < index_[i - 1]))) {
      dist_[i] = dist_[i - 1];
      index_[i] = index_[i - 1];
      --i;
    }
    dist_[i] = dist;
    index_[i] = index;
  }
  // Writes the points kept to `index` and `dist` (k entries each) as FLANN's radiusSearch
  // does: the next entry after them marked unused (-1, infinity), the rest left as they are.
  void copy(int* index, float* dist) const {
    for (int m = 0; m < size_; ++m) {
      index[m] = static_cast<int>(index_[m]);
      dist[m] = dist_[m];
    }
    if (size_ < capacity_) {
      index[size_] = -1;
      dist[size_] = std::numeric_limits<float>::infinity();
    }
  }

 private:
  float radius_;
  int capacity_;
  int size_ = 0;
  std::array<float, MAX_RESULT_POINTS> dist_{};
  std::array<std::size_t, MAX_RESULT_POINTS> index_{};
};

// Each point's `k` nearest neighbours in `index` within the float `bound`, nearest first
// (index -1 where fewer lie within it; entries k i to k i + k - 1): FLANN's radiusSearch
// with `max_neighbors = k`, one query at a time with one result set.
template <typename Points, typename Get>
Nearest k_nearest_within(const BatchIndex& index, std::size_t n, const Points& points, Get get,
                         int k, float bound) {
  if (k < 1 || k > MAX_RESULT_POINTS) throw std::logic_error("k_nearest_within: k out of range");
  Nearest out{std::vector<int>(k * n, -1), std::vector<float>(k * n)};
  flann::SearchParams params(-1, 0.0f);  // as pcl::KdTreeFLANN: exact
  SortedRadiusResultSet found(bound, k);
  for (std::size_t i = 0; i < n; ++i) {
    const pcl::PointXYZ& p = get(points, i);
    const float query[3] = {p.x, p.y, p.z};
    found.clear();
    index.index->findNeighbors(found, query, params);
    found.copy(&out.index[k * i], &out.distance_sqr[k * i]);
  }
  return out;
}

// Each point's nearest neighbour in `index` whose squared distance is at most `max_sqr`
// (index -1 when there is none). A search bounded this way prunes every branch farther
// away, where PCL's unbounded one first walks to whatever is nearest however far; both keep
// the first of equally near points in the same tree order.
template <typename Points, typename Get>
Nearest nearest_within(const BatchIndex& index, std::size_t n, const Points& points, Get get,
                       double max_sqr) {
  Nearest out = k_nearest_within(index, n, points, get, 1, exclusive_bound(max_sqr));
  for (std::size_t i = 0; i < n; ++i) {
    if (out.index[i] >= 0 && !(out.distance_sqr[i] <= max_sqr)) out.index[i] = -1;
  }
  return out;
}

// FLANN's squared distance (L2_Simple<float>: ((0 + dx^2) + dy^2) + dz^2, in float).
inline float flann_distance_sqr(const float* a, const pcl::PointXYZ& q) {
  float result = 0.0f;
  float diff = q.x - a[0];
  result += diff * diff;
  diff = q.y - a[1];
  result += diff * diff;
  diff = q.z - a[2];
  result += diff * diff;
  return result;
}

// Relative margin on the certificate below: far wider than float rounding of distances
// (a few 1e-7), so FLANN's float search picks the same point.
constexpr double CERTIFY_MARGIN = 1e-4;

// Points an ICP source point keeps from its last search.
constexpr int ANCHOR_POINTS = MAX_RESULT_POINTS;

// How far past the correspondence distance a source point with no target point within it
// looks for its nearest one: while it moves less than the gap, it has no correspondence.
constexpr double LONELY_REACH = 2.0;

// PCL's CorrespondenceEstimation with the same answers, but one FLANN call per ICP iteration
// instead of one per source point: PCL's per-point path enters an OpenMP region and allocates
// for every query, which made that overhead most of ICP's time. Nearest neighbours come from
// an index identical to PCL's KdTreeFLANN, so correspondences are the same as PCL's.
// Between iterations a source point moves little: each keeps the ANCHOR_POINTS nearest
// target points of its last search, and while it stays nearer to one of them than any other
// target point can have come (the last search's reach less how far it moved since), its
// nearest point is that one and the kd-tree is not searched (about 6 queries in 10 on a belt
// scan). A source point with no target point within the distance (model surface the scan
// does not show: two in three of the searches otherwise) keeps how far the nearest one lay,
// up to LONELY_REACH times the distance, and is not searched while it has not moved close
// enough to reach it. Equally near points go to the single search, which picks as PCL does.
class BatchCorrespondenceEstimation
    : public pcl::registration::CorrespondenceEstimation<pcl::PointXYZ, pcl::PointXYZ, double> {
 public:
  explicit BatchCorrespondenceEstimation(const BatchIndex* index) : index_(index) {}

  void determineCorrespondences(pcl::Correspondences& correspondences,
                                double max_distance) override {
    check_interrupt("ICP iteration");  // once per ICP iteration
    if (!initCompute()) return;
    const std::size_t n = indices_->size();
    const double max_sqr = max_distance * max_distance;
    const float bound = exclusive_bound(max_sqr);
    if (anchors_.size() != n) anchors_.assign(n, Anchor{});
    std::vector<int> nearest(n, -1);
    std::vector<float> distance_sqr(n, 0.0f);
    auto take = [&](std::size_t i, int j, float d2) {
      if (j >= 0 && d2 < bound && d2 <= max_sqr) {
        nearest[i] = j;
        distance_sqr[i] = d2;
      }
    };
    std::vector<std::size_t> searched;  // re-anchored with a new search
    std::vector<std::size_t> tied;      // two points equally near: the single search decides
    for (std::size_t i = 0; i < n; ++i) {
      const pcl::PointXYZ& q = (*input_)[(*indices_)[i]];
      const Anchor& a = anchors_[i];
      if (a.count == 0 && a.reach > 0.0) {
        // No target point lay within a.reach of the anchor, so none within a.reach - moved
        // of q: no correspondence while that is beyond the distance.
        const double dx = double(q.x) - a.x, dy = double(q.y) - a.y, dz = double(q.z) - a.z;
        const double moved = std::sqrt(dx * dx + dy * dy + dz * dz);
        if ((a.reach - moved) * (1.0 - CERTIFY_MARGIN) > max_distance) continue;
      } else if (a.count > 0) {
        // Every point not cached lay at least a.reach from the anchor, so at least
        // a.reach - moved from q: the nearest cached point is q's nearest when nearer.
        const double dx = double(q.x) - a.x, dy = double(q.y) - a.y, dz = double(q.z) - a.z;
        const double moved = std::sqrt(dx * dx + dy * dy + dz * dz);
        int best = -1;
        float best_d2 = std::numeric_limits<float>::infinity();
        bool tie = false;
        for (int m = 0; m < a.count; ++m) {
          const float d2 = flann_distance_sqr(&index_->xyz[3 * std::size_t(a.cached[m])], q);
          if (d2 < best_d2) {
            best = a.cached[m];
            best_d2 = d2;
            tie = false;
          } else if (d2 == best_d2) {
            tie = true;
          }
        }
        if ((std::sqrt(double(best_d2)) + moved) * (1.0 + CERTIFY_MARGIN) < a.reach) {
          if (tie) {
            tied.push_back(i);
          } else {
            take(i, best, best_d2);
          }
          continue;
        }
      }
      searched.push_back(i);
    }
    // Within the correspondence distance only: the correspondences PCL would keep, and the
    // nearest few around them, which anchor the next iterations.
    const Nearest near = k_nearest_within(
        *index_, searched.size(), *input_,
        [this, &searched](const PointCloudXYZ& cloud, std::size_t k) -> const pcl::PointXYZ& {
          return cloud[(*indices_)[searched[k]]];
        },
        ANCHOR_POINTS, bound);
    std::vector<std::size_t> lonely;  // no target point within the distance
    for (std::size_t k = 0; k < searched.size(); ++k) {
      const std::size_t i = searched[k];
      const int* idx = &near.index[ANCHOR_POINTS * k];
      const float* d2 = &near.distance_sqr[ANCHOR_POINTS * k];
      Anchor& a = anchors_[i];
      a = Anchor{};
      if (idx[0] < 0) {
        lonely.push_back(i);
        continue;
      }
      int count = 0;
      while (count < ANCHOR_POINTS && idx[count] >= 0) {
        a.cached[count] = idx[count];
        ++count;
      }
      if (count > 1 && !(d2[0] < d2[1])) {
        tied.push_back(i);
      } else {
        take(i, idx[0], d2[0]);
      }
      const pcl::PointXYZ& q = (*input_)[(*indices_)[i]];
      a.x = q.x;
      a.y = q.y;
      a.z = q.z;
      a.count = count;
      // Fewer within the bound: every other point lies at least that far.
      a.reach = std::sqrt(double(count == ANCHOR_POINTS ? d2[ANCHOR_POINTS - 1] : bound));
    }
    if (!lonely.empty()) {
      const float far = exclusive_bound(LONELY_REACH * LONELY_REACH * max_sqr);
      auto point = [&](const PointCloudXYZ& cloud, std::size_t t) -> const pcl::PointXYZ& {
        return cloud[(*indices_)[lonely[t]]];
      };
      const Nearest nearest = k_nearest_within(*index_, lonely.size(), *input_, point, 1, far);
      for (std::size_t t = 0; t < lonely.size(); ++t) {
        Anchor& a = anchors_[lonely[t]];
        const pcl::PointXYZ& q = point(*input_, t);
        a.x = q.x;
        a.y = q.y;
        a.z = q.z;
        a.count = 0;
        // Every target point lies at least this far (none found: the search's reach).
        a.reach = std::sqrt(double(nearest.index[t] >= 0 ? nearest.distance_sqr[t] : far));
      }
    }
    if (!tied.empty()) {
      const Nearest single = nearest_within(
          *index_, tied.size(), *input_,
          [&](const PointCloudXYZ& cloud, std::size_t t) -> const pcl::PointXYZ& {
            return cloud[(*indices_)[tied[t]]];
          },
          max_sqr);
      for (std::size_t t = 0; t < tied.size(); ++t) {
        take(tied[t], single.index[t], single.distance_sqr[t]);
      }
    }
    correspondences.resize(n);
    std::size_t valid = 0;
    for (std::size_t i = 0; i < n; ++i) {
      if (nearest[i] < 0) continue;
      correspondences[valid++] =
          pcl::Correspondence((*indices_)[i], nearest[i], distance_sqr[i]);
    }
    correspondences.resize(valid);
    deinitCompute();
  }

  // PCL's determineReciprocalCorrespondences, batched: each source point's nearest target
  // point within the distance, kept when that target point's nearest source point (over the
  // same source indices, an index built as PCL's KdTreeFLANN) is this one, within the
  // distance too.
  void determineReciprocalCorrespondences(pcl::Correspondences& correspondences,
                                          double max_distance) override {
    check_interrupt("ICP iteration");
    if (!initCompute()) return;
    const std::size_t n = indices_->size();
    const double max_sqr = max_distance * max_distance;
    const Nearest near = nearest_within(
        *index_, n, *input_,
        [this](const PointCloudXYZ& cloud, std::size_t i) -> const pcl::PointXYZ& {
          return cloud[(*indices_)[i]];
        },
        max_sqr);
    BatchIndex source;
    source.xyz.reserve(n * 3);
    for (std::size_t i = 0; i < n; ++i) {
      const pcl::PointXYZ& p = (*input_)[(*indices_)[i]];
      source.xyz.push_back(p.x);
      source.xyz.push_back(p.y);
      source.xyz.push_back(p.z);
    }
    correspondences.clear();
    if (n == 0) {
      deinitCompute();
      return;
    }
    source.index = build_kd_tree(source.xyz, n);
    std::vector<std::size_t> matched;
    for (std::size_t i = 0; i < n; ++i) {
      if (near.index[i] >= 0) matched.push_back(i);
    }
    const Nearest back = nearest_within(
        source, matched.size(), *target_,
        [&](const PointCloudXYZ& cloud, std::size_t k) -> const pcl::PointXYZ& {
          return cloud[near.index[matched[k]]];
        },
        max_sqr);
    correspondences.reserve(matched.size());
    for (std::size_t k = 0; k < matched.size(); ++k) {
      const std::size_t i = matched[k];
      if (back.index[k] != static_cast<int>(i)) continue;
      correspondences.push_back(
          pcl::Correspondence((*indices_)[i], near.index[i], near.distance_sqr[i]));
    }
    deinitCompute();
  }

  typename pcl::registration::CorrespondenceEstimationBase<pcl::PointXYZ, pcl::PointXYZ,
                                                           double>::Ptr
  clone() const override {
    return std::make_shared<BatchCorrespondenceEstimation>(*this);
  }

 private:
  const BatchIndex* index_;
  // Where a source point was last searched, the ANCHOR_POINTS nearest target points there
  // (fewer when fewer lay within the bound) and the reach: the distance of the last of them,
  // or the bound's when fewer were found. With none within the bound (count 0), the reach is
  // the nearest one's distance, or LONELY_REACH bounds when none lay within that either; 0
  // before the first search.
  struct Anchor {
    double x = 0.0, y = 0.0, z = 0.0;
    std::array<int, ANCHOR_POINTS> cached{};
    int count = 0;
    double reach = 0.0;
  };
  std::vector<Anchor> anchors_;
};


// Registration::getFitnessScore(max_range) with the same answer: the mean squared distance
// of the aligned source points whose nearest target point lies within `max_range` (PCL
// compares the squared distance with it, so that is the bound here too). A point beyond it
// is not counted either way; same points, same order, same float distances: the same sum.
double bounded_fitness(const BatchIndex& index, const PointCloudXYZ& source,
                       const Eigen::Matrix4d& transformation, double max_range) {
  PointCloudXYZ aligned;
  pcl::transformPointCloud(source, aligned, transformation);
  const std::size_t n = aligned.size();
  if (n == 0) return std::numeric_limits<double>::max();
  const Nearest near = nearest_within(
      index, n, aligned,
      [](const PointCloudXYZ& cloud, std::size_t i) -> const pcl::PointXYZ& { return cloud[i]; },
      max_range);
  double sum = 0.0;
  int counted = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (near.index[i] < 0) continue;
    sum += near.distance_sqr[i];
    ++counted;
  }
  return counted > 0 ? sum / counted : std::numeric_limits<double>::max();
}

using FeatureCloud = pcl::PointCloud<pcl::FPFHSignature33>;

FeatureCloud::Ptr to_features(rust::Slice<const float> values, const char* what) {
  if (values.size() % 33 != 0) fail(what, ": ", values.size(), " floats is not a whole number of 33-bin FPFH descriptors");
  const std::size_t n = values.size() / 33;
  if (n == 0) fail(what, ": no descriptors");
  FeatureCloud::Ptr cloud(new FeatureCloud);
  cloud->resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    for (int d = 0; d < 33; ++d) {
      const float v = values[i * 33 + d];
      if (!std::isfinite(v)) fail(what, ": descriptor ", i, " has a non-finite bin");
      (*cloud)[i].histogram[d] = v;
    }
  }
  cloud->width = static_cast<std::uint32_t>(n);
  cloud->height = 1;
  return cloud;
}

pcl::Correspondences to_pcl(rust::Slice<const Correspondence> corrs, std::size_t n_source,
                            std::size_t n_target) {
  pcl::Correspondences out;
  out.reserve(corrs.size());
  for (const auto& c : corrs) {
    if (c.query >= n_source || c.matched >= n_target) {
      fail("correspondence (", c.query, " -> ", c.matched, ") is out of range for clouds of ",
           n_source, " and ", n_target, " points");
    }
    out.emplace_back(static_cast<pcl::index_t>(c.query), static_cast<pcl::index_t>(c.matched),
                     c.distance);
  }
  return out;
}

template <typename Matrix>
void to_row_major(const Matrix& m, std::array<double, 16>& out) {
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) out[r * 4 + c] = static_cast<double>(m(r, c));
}

Eigen::Matrix4d from_row_major(const std::array<double, 16>& a) {
  Eigen::Matrix4d m;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m(r, c) = a[r * 4 + c];
  return m;
}

// PCL correspondences as the bridge's plain struct.
void append_rust(const pcl::Correspondences& corrs, rust::Vec<Correspondence>& out) {
  out.reserve(out.size() + corrs.size());
  for (const auto& c : corrs) {
    out.push_back(Correspondence{static_cast<std::uint32_t>(c.index_query),
                                 static_cast<std::uint32_t>(c.index_match), c.distance});
  }
}

// A rejector's answer: the kept correspondences (only when it converged) and its transform.
SacResult sac_result(bool converged, const pcl::Correspondences& kept, const Eigen::Matrix4f& t) {
  SacResult out;
  out.converged = converged;
  to_row_major(t, out.transform);
  out.rotation_det = static_cast<double>(t.topLeftCorner<3, 3>().determinant());
  if (converged) append_rust(kept, out.kept);
  return out;
}

// ICP that also reports how many iterations it ran (a protected member in PCL).
class CountingIcp : public pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ, double> {
 public:
  int iterations() const { return nr_iterations_; }
};

}  // namespace

// pcl::registration::CorrespondenceEstimation in FPFH space: for every source descriptor, its
// nearest target descriptor (distance = squared L2 between histograms).
rust::Vec<Correspondence> match_features(rust::Slice<const float> source_features,
                                         rust::Slice<const float> target_features) {
  const auto src = to_features(source_features, "match_features source");
  const auto tgt = to_features(target_features, "match_features target");
  pcl::registration::CorrespondenceEstimation<pcl::FPFHSignature33, pcl::FPFHSignature33> est;
  est.setInputSource(src);
  est.setInputTarget(tgt);
  pcl::Correspondences corrs;
  est.determineCorrespondences(corrs);
  rust::Vec<Correspondence> out;
  append_rust(corrs, out);
  return out;
}

// pcl::registration::CorrespondenceRejectorSampleConsensus (thesis 3.4.2.5): RANSAC over the
// correspondences with `max_iterations` and `inlier_threshold` (same units as the points).
// Deterministic: each call builds a fresh PCL model seeded with 12345. `converged` is false
// when PCL found no model (it then returns the input unchanged and an identity transform).
SacResult reject_sample_consensus(rust::Slice<const float> source_xyz,
                                  rust::Slice<const float> target_xyz,
                                  rust::Slice<const Correspondence> correspondences,
                                  float inlier_threshold, std::uint32_t max_iterations) {
  check_positive(inlier_threshold, "SAC inlier threshold");
  if (max_iterations == 0) fail("SAC rejector needs at least one iteration");
  const auto src = to_cloud(source_xyz, "SAC source");
  const auto tgt = to_cloud(target_xyz, "SAC target");
  const auto corrs = to_pcl(correspondences, src->size(), tgt->size());
  if (corrs.size() < 3) fail("SAC rejector needs at least 3 correspondences, got ", corrs.size());

  pcl::registration::CorrespondenceRejectorSampleConsensus<pcl::PointXYZ> rej;
  rej.setInputSource(src);
  rej.setInputTarget(tgt);
  rej.setInlierThreshold(inlier_threshold);
  rej.setMaximumIterations(static_cast<int>(max_iterations));
  rej.setRefineModel(false);
  rej.setSaveInliers(true);
  pcl::Correspondences kept;
  rej.getRemainingCorrespondences(corrs, kept);
  pcl::Indices inliers;
  rej.getInliersIndices(inliers);

  return sac_result(!inliers.empty(), kept, rej.getBestTransformation());
}

namespace {

// PCL's registration model, exposing the squared residuals its selectWithinDistance computed
// (a protected member in PCL), so one pass over the correspondences serves every threshold.
class SweepModel : public pcl::SampleConsensusModelRegistration<pcl::PointXYZ> {
 public:
  using pcl::SampleConsensusModelRegistration<pcl::PointXYZ>::SampleConsensusModelRegistration;
  const std::vector<double>& last_sqr_residuals() const { return error_sqr_dists_; }
};

// What CorrespondenceRejectorSampleConsensus::getRemainingCorrespondences keeps for RANSAC's
// inliers (source indices): the correspondence of each, in inlier order.
pcl::Correspondences kept_correspondences(const pcl::Correspondences& corrs,
                                          const pcl::Indices& inliers) {
  std::unordered_map<int, int> index_to_correspondence;
  for (int i = 0; i < static_cast<int>(corrs.size()); ++i)
    index_to_correspondence[corrs[i].index_query] = i;
  pcl::Correspondences kept;
  kept.reserve(inliers.size());
  for (const auto& inlier : inliers) kept.push_back(corrs[index_to_correspondence[inlier]]);
  return kept;
}

}  // namespace

// The thesis's threshold sweep (Algorithm 1 step iii): CorrespondenceRejectorSampleConsensus
// run once per threshold on the same correspondences, with the same answers, in one pass.
// Every rejector run builds a fresh SampleConsensusModelRegistration seeded with 12345, so all
// runs draw the same samples and fit the same candidate transforms; they differ only in which
// candidates they count as better and when their adaptive iteration bound stops them. This
// replays pcl::RandomSampleConsensus::computeModel (ransac.hpp, PCL 1.13) for every threshold
// at once: one draw and one PCL model fit per iteration, one residual pass at the largest
// threshold (PCL's own selectWithinDistance), then each still-running threshold counts its
// inliers from those residuals exactly as countWithinDistance compares them. The bridge test
// `sweep_matches_one_rejector_per_threshold` checks the results are identical.
rust::Vec<SacResult> reject_sample_consensus_sweep(rust::Slice<const float> source_xyz,
                                                   rust::Slice<const float> target_xyz,
                                                   rust::Slice<const Correspondence> correspondences,
                                                   rust::Slice<const float> inlier_thresholds,
                                                   std::uint32_t max_iterations) {
  if (inlier_thresholds.empty()) fail("SAC sweep needs at least one threshold");
  for (float t : inlier_thresholds) check_positive(t, "SAC inlier threshold");
  if (max_iterations == 0) fail("SAC rejector needs at least one iteration");
  if (max_iterations > static_cast<std::uint32_t>(std::numeric_limits<int>::max() / 10)) {
    fail("SAC rejector: ", max_iterations, " iterations is too many");
  }
  const auto src = to_cloud(source_xyz, "SAC source");
  const auto tgt = to_cloud(target_xyz, "SAC target");
  const auto corrs = to_pcl(correspondences, src->size(), tgt->size());
  if (corrs.size() < 3) fail("SAC rejector needs at least 3 correspondences, got ", corrs.size());

  pcl::Indices source_indices(corrs.size()), target_indices(corrs.size());
  for (std::size_t i = 0; i < corrs.size(); ++i) {
    source_indices[i] = corrs[i].index_query;
    target_indices[i] = corrs[i].index_match;
  }
  auto model = std::make_shared<SweepModel>(src, source_indices);
  model->setInputTarget(tgt, target_indices);

  // One run per threshold; the threshold is a double holding the float, as the rejector's.
  struct Run {
    double threshold = 0.0, sqr_threshold = 0.0;
    bool running = true;
    std::size_t best_count = 0;
    double k = std::numeric_limits<double>::max();
    Eigen::VectorXf coefficients;
  };
  std::vector<Run> runs;
  double widest = 0.0;
  for (float t : inlier_thresholds) {
    const double th = t;
    Run run;
    run.threshold = th;
    run.sqr_threshold = th * th;
    runs.push_back(std::move(run));
    widest = std::max(widest, th);
  }
  const double probability = pcl::RandomSampleConsensus<pcl::PointXYZ>(model).getProbability();
  const double log_probability = std::log(1.0 - probability);
  const double one_over_indices = 1.0 / static_cast<double>(model->getIndices()->size());
  const int max_iter = static_cast<int>(max_iterations);
  const unsigned max_skip = max_iterations * 10;
  unsigned skipped = 0;
  int iterations = 0;
  pcl::Indices selection, within;
  Eigen::VectorXf coefficients(model->getModelSize());

  auto running = [&runs] {
    return std::any_of(runs.begin(), runs.end(), [](const Run& r) { return r.running; });
  };
  while (running()) {
    if (iterations % 16 == 0) check_interrupt("RANSAC threshold sweep");
    model->getSamples(iterations, selection);
    if (selection.empty()) break;
    if (!model->computeModelCoefficients(selection, coefficients)) {
      if (++skipped < max_skip) continue;
      break;
    }
    model->selectWithinDistance(coefficients, widest, within);
    const auto& residuals = model->last_sqr_residuals();
    ++iterations;
    for (auto& run : runs) {
      if (!run.running) continue;
      const auto count = static_cast<std::size_t>(
          std::count_if(residuals.begin(), residuals.end(),
                        [&run](double d) { return d < run.sqr_threshold; }));
      if (count > run.best_count) {
        run.best_count = count;
        run.coefficients = coefficients;
        const double w = static_cast<double>(count) * one_over_indices;
        double p_outliers = 1.0 - std::pow(w, static_cast<double>(selection.size()));
        p_outliers = std::max(std::numeric_limits<double>::epsilon(), p_outliers);
        p_outliers = std::min(1.0 - std::numeric_limits<double>::epsilon(), p_outliers);
        run.k = log_probability / std::log(p_outliers);
      }
      if (iterations > run.k || iterations > max_iter) run.running = false;
    }
  }

  rust::Vec<SacResult> out;
  pcl::Indices inliers;
  for (const auto& run : runs) {
    inliers.clear();
    if (run.best_count > 0) model->selectWithinDistance(run.coefficients, run.threshold, inliers);
    // As the rejector: fewer than 3 inliers is no consensus (identity, nothing kept).
    const bool converged = inliers.size() >= 3;
    Eigen::Matrix4f t = Eigen::Matrix4f::Identity();
    if (converged) {
      for (int r = 0; r < 4; ++r) t.row(r) = run.coefficients.segment<4>(4 * r);
    }
    out.push_back(sac_result(converged, kept_correspondences(corrs, inliers), t));
  }
  return out;
}

// pcl::registration::TransformationEstimationSVD (thesis 3.5.1): closed-form rigid transform
// (Umeyama) minimising the distances between corresponding points, source -> target.
Transform estimate_svd(rust::Slice<const float> source_xyz, rust::Slice<const float> target_xyz,
                       rust::Slice<const Correspondence> correspondences) {
  const auto src = to_cloud(source_xyz, "SVD source");
  const auto tgt = to_cloud(target_xyz, "SVD target");
  const auto corrs = to_pcl(correspondences, src->size(), tgt->size());
  if (corrs.size() < 3) fail("SVD needs at least 3 correspondences, got ", corrs.size());
  pcl::registration::TransformationEstimationSVD<pcl::PointXYZ, pcl::PointXYZ, double> svd;
  Eigen::Matrix4d t;
  svd.estimateRigidTransformation(*src, *tgt, corrs, t);
  if (!t.allFinite()) throw std::runtime_error("SVD produced a non-finite transform");
  Transform out;
  to_row_major(t, out.m);
  return out;
}

// pcl::IterativeClosestPoint (thesis 3.6.1) of `source_xyz` onto the uploaded `target`,
// reusing the target's kd-tree (no rebuild per call).
IcpResult icp_align(const Cloud& target, rust::Slice<const float> source_xyz,
                    const IcpParams& params) {
  check_positive(params.max_correspondence_distance, "ICP max correspondence distance");
  check_positive(params.transformation_epsilon, "ICP transformation epsilon");
  if (params.max_iterations == 0) fail("ICP needs at least one iteration");
  const Eigen::Matrix4d guess = from_row_major(params.initial);
  if (!guess.allFinite()) fail("ICP initial guess has a non-finite entry");
  const auto src = to_cloud(source_xyz, "ICP source");
  const auto& t = target.impl();

  CountingIcp icp;
  if (params.batch_correspondences) {
    icp.setCorrespondenceEstimation(
        std::make_shared<BatchCorrespondenceEstimation>(&batch_index(t)));
  }
  icp.setInputSource(src);
  icp.setInputTarget(t.points);
  icp.setSearchMethodTarget(t.tree, /*force_no_recompute=*/true);
  icp.setMaxCorrespondenceDistance(params.max_correspondence_distance);
  icp.setUseReciprocalCorrespondences(params.reciprocal);
  icp.setMaximumIterations(static_cast<int>(params.max_iterations));
  icp.setTransformationEpsilon(params.transformation_epsilon);
  if (params.relative_mse > 0.0) {
    if (!std::isfinite(params.relative_mse)) fail("ICP relative MSE threshold must be finite");
    icp.setEuclideanFitnessEpsilon(params.relative_mse);
  }
  PointCloudXYZ aligned;
  icp.align(aligned, guess);

  IcpResult out;
  out.converged = icp.hasConverged();
  to_row_major(icp.getFinalTransformation(), out.transform);
  out.fitness = params.batch_correspondences
                    ? bounded_fitness(batch_index(t), *src, icp.getFinalTransformation(),
                                      params.max_correspondence_distance)
                    : icp.getFitnessScore(params.max_correspondence_distance);
  out.iterations = static_cast<std::uint32_t>(std::max(icp.iterations(), 0));
  out.state = static_cast<std::int32_t>(icp.getConvergeCriteria()->getConvergenceState());
  return out;
}

}  // namespace binpick
