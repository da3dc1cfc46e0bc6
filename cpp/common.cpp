// Cloud upload, shared kd-tree queries and input validation (pcl_common, pcl_search).
#include <pcl/common/common.h>
#include <pcl/console/print.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <thread>

#include "binpick-pcl/src/ffi.rs.h"
#include "internal.h"

// The kd-tree classes every translation unit uses, compiled here once (internal.h).
BINPICK_SEARCH_TEMPLATES(BINPICK_INSTANTIATE_TEMPLATE)

namespace binpick {

Cloud::Cloud(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Cloud::~Cloud() = default;
std::size_t Cloud::size() const { return impl_->points->size(); }

void set_pcl_verbosity(std::int32_t level) {
  if (level < 0 || level > static_cast<std::int32_t>(pcl::console::L_VERBOSE)) {
    fail("PCL verbosity level ", level, " is outside 0 (always) .. 5 (verbose)");
  }
  pcl::console::setVerbosityLevel(static_cast<pcl::console::VERBOSITY_LEVEL>(level));
}

void check_positive(double value, const char* name) {
  if (!(std::isfinite(value) && value > 0.0)) {
    fail(name, " must be a positive finite number, got ", value);
  }
}

void throw_interrupted(const char* where) {
  throw std::runtime_error(std::string(kInterruptedMarker) + where);
}

void check_interrupt(const char* where) {
  if (interrupt_requested()) throw_interrupted(where);
}

PointCloudXYZ::Ptr to_cloud(rust::Slice<const float> xyz, const char* what, bool allow_empty) {
  if (xyz.size() % 3 != 0) {
    fail(what, ": ", xyz.size(), " floats is not a whole number of xyz points");
  }
  const std::size_t n = xyz.size() / 3;
  if (n == 0 && !allow_empty) {
    fail(what, ": the cloud is empty");
  }
  if (n > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max())) {
    fail(what, ": ", n, " points exceed PCL's 32-bit index range");
  }
  PointCloudXYZ::Ptr cloud(new PointCloudXYZ);
  cloud->resize(n);
  const float* p = xyz.data();
  for (std::size_t i = 0; i < n; ++i, p += 3) {
    if (!(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]))) {
      fail(what, ": point ", i, " has a non-finite coordinate");
    }
    (*cloud)[i] = pcl::PointXYZ(p[0], p[1], p[2]);
  }
  cloud->width = static_cast<std::uint32_t>(n);
  cloud->height = 1;
  cloud->is_dense = true;
  return cloud;
}

pcl::Indices to_indices(rust::Slice<const std::uint32_t> idx, std::size_t n, const char* what) {
  pcl::Indices out;
  out.reserve(idx.size());
  for (std::uint32_t i : idx) {
    if (i >= n) {
      fail(what, ": index ", i, " is out of range for a cloud of ", n, " points");
    }
    out.push_back(static_cast<pcl::index_t>(i));
  }
  return out;
}

pcl::search::KdTree<pcl::PointXYZ>::Ptr make_tree(const PointCloudXYZ::Ptr& cloud) {
  pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>(false));
  tree->setInputCloud(cloud);
  return tree;
}

void check_grid(const PointCloudXYZ& cloud, float leaf, const char* what) {
  check_positive(leaf, "leaf size");
  Eigen::Vector4f min_p, max_p;
  pcl::getMinMax3D(cloud, min_p, max_p);
  std::int64_t cells = 1;
  for (int i = 0; i < 3; ++i) {
    const double span = std::floor(max_p[i] / leaf) - std::floor(min_p[i] / leaf) + 1.0;
    if (!(span < 2.0e9)) {
      fail(what, ": leaf ", leaf, " is too small for a cloud spanning ", max_p[i] - min_p[i],
           " along axis ", i);
    }
    cells *= static_cast<std::int64_t>(span);
    if (cells > std::numeric_limits<std::int32_t>::max()) {
      fail(what, ": leaf ", leaf, " is too small for this cloud's extent (",
           max_p[0] - min_p[0], " x ", max_p[1] - min_p[1], " x ", max_p[2] - min_p[2],
           "): the voxel grid would exceed PCL's 32-bit cell index");
    }
  }
}

namespace {
// The cloud and its kd-tree, as every upload starts.
std::unique_ptr<Cloud::Impl> new_cloud(rust::Slice<const float> xyz, const char* what) {
  auto impl = std::make_unique<Cloud::Impl>();
  impl->points = to_cloud(xyz, what);
  impl->tree = make_tree(impl->points);
  return impl;
}
}  // namespace

std::unique_ptr<Cloud> upload_cloud(rust::Slice<const float> xyz) {
  return std::make_unique<Cloud>(new_cloud(xyz, "upload_cloud"));
}

// A pcl::search::Search answering radius searches of the cloud's own points from neighbour
// lists found once, by one kd-tree search per point at the largest radius. PCL's estimators
// (NormalEstimationOMP, FPFHEstimationOMP) search every point's neighbourhood again for each
// radius and each pass; with 4 FPFH radii that is 12 kd-tree searches per point, now one.
// The answers are the kd-tree's own: FLANN's single-index kd-tree visits its nodes in an
// order fixed by the query alone (the radius only prunes subtrees with no point inside it)
// and returns unsorted results in visiting order, keeping a point when its float squared
// distance is below float(radius^2). Filtering the largest-radius list with that same test
// therefore gives the same neighbours, distances and order as a search at the smaller radius.
// Other queries (foreign clouds, larger radii, bounded counts, k-NN) go to the kd-tree.
class CachedNeighbourhoods : public pcl::search::Search<pcl::PointXYZ> {
  // Points searched between two polls of `interrupt_requested` (a few milliseconds).
  static constexpr std::size_t kInterruptPollPoints = 4096;

 public:
  // Builds the lists on `threads` threads (each a contiguous range of points, joined in
  // order); returns null if they would hold more than `max_entries` neighbours.
  static std::shared_ptr<CachedNeighbourhoods> build(
      const PointCloudXYZ::Ptr& cloud, const pcl::search::KdTree<pcl::PointXYZ>::Ptr& tree,
      double radius, std::size_t max_entries, unsigned threads) {
    struct Part {
      std::vector<std::size_t> counts;
      pcl::Indices neighbours;
      std::vector<float> sqr_distances;
      bool too_many = false;
    };
    const std::size_t n = cloud->size();
    threads = static_cast<unsigned>(std::clamp<std::size_t>(threads, 1, std::max<std::size_t>(1, n / 1000)));
    std::vector<Part> parts(threads);
    // Set by the calling thread when the Rust caller asks to stop; helpers see it too.
    std::atomic<bool> stop{false};
    auto fill = [&](unsigned t) {
      Part& part = parts[t];
      pcl::Indices idx;
      std::vector<float> d2;
      for (std::size_t i = n * t / threads; i < n * (t + 1) / threads; ++i) {
        if (i % kInterruptPollPoints == 0) {
          if (t == 0 && interrupt_requested()) stop.store(true, std::memory_order_relaxed);
          if (stop.load(std::memory_order_relaxed)) return;
        }
        tree->radiusSearch((*cloud)[i], radius, idx, d2);
        if (part.neighbours.size() + idx.size() > max_entries) {
          part.too_many = true;
          return;
        }
        part.counts.push_back(idx.size());
        part.neighbours.insert(part.neighbours.end(), idx.begin(), idx.end());
        part.sqr_distances.insert(part.sqr_distances.end(), d2.begin(), d2.end());
      }
    };
    std::vector<std::thread> helpers;
    for (unsigned t = 1; t < threads; ++t) helpers.emplace_back(fill, t);
    fill(0);
    for (auto& h : helpers) h.join();
    if (stop.load(std::memory_order_relaxed)) throw_interrupted("neighbourhood search");

    std::shared_ptr<CachedNeighbourhoods> cache(new CachedNeighbourhoods(cloud, tree, radius));
    auto& c = *cache;
    c.offsets_.reserve(n + 1);
    c.offsets_.push_back(0);
    for (auto& part : parts) {
      if (part.too_many || c.neighbours_.size() + part.neighbours.size() > max_entries) {
        return nullptr;
      }
      for (std::size_t k : part.counts) c.offsets_.push_back(c.offsets_.back() + k);
      c.neighbours_.insert(c.neighbours_.end(), part.neighbours.begin(), part.neighbours.end());
      c.sqr_distances_.insert(c.sqr_distances_.end(), part.sqr_distances.begin(),
                              part.sqr_distances.end());
    }
    return cache;
  }

  // Radius of the cached lists, point units.
  double radius() const { return radius_; }

  int radiusSearch(const PointCloud& cloud, pcl::index_t index, double radius,
                   pcl::Indices& k_indices, std::vector<float>& k_sqr_distances,
                   unsigned int max_nn = 0) const override {
    if (&cloud != input_.get() || max_nn != 0 || radius > radius_ || index < 0 ||
        static_cast<std::size_t>(index) + 1 >= offsets_.size()) {
      return tree_->radiusSearch(cloud[index], radius, k_indices, k_sqr_distances, max_nn);
    }
    const float limit = static_cast<float>(radius * radius);  // as pcl::KdTreeFLANN
    k_indices.clear();
    k_sqr_distances.clear();
    for (std::size_t j = offsets_[index]; j < offsets_[index + 1]; ++j) {
      if (sqr_distances_[j] < limit) {  // as FLANN's RadiusResultSet
        k_indices.push_back(neighbours_[j]);
        k_sqr_distances.push_back(sqr_distances_[j]);
      }
    }
    return static_cast<int>(k_indices.size());
  }

  int radiusSearch(pcl::index_t index, double radius, pcl::Indices& k_indices,
                   std::vector<float>& k_sqr_distances, unsigned int max_nn = 0) const override {
    return radiusSearch(*input_, index, radius, k_indices, k_sqr_distances, max_nn);
  }

  // PCL's Euclidean clustering queries by point reference into the cloud; such a query is
  // the cloud's own point and is served from the cache too.
  int radiusSearch(const pcl::PointXYZ& point, double radius, pcl::Indices& k_indices,
                   std::vector<float>& k_sqr_distances, unsigned int max_nn = 0) const override {
    const auto& pts = input_->points;
    if (!pts.empty() && &point >= pts.data() && &point < pts.data() + pts.size()) {
      const auto index = static_cast<pcl::index_t>(&point - pts.data());
      return radiusSearch(*input_, index, radius, k_indices, k_sqr_distances, max_nn);
    }
    return tree_->radiusSearch(point, radius, k_indices, k_sqr_distances, max_nn);
  }

  int nearestKSearch(const pcl::PointXYZ& point, int k, pcl::Indices& k_indices,
                     std::vector<float>& k_sqr_distances) const override {
    return tree_->nearestKSearch(point, k, k_indices, k_sqr_distances);
  }

  // PCL's estimators and clustering re-point their search method at their input (clustering
  // with the indices of every point, in order, which leaves the answers unchanged); the cache
  // only serves the cloud it was built on, whole.
  void setInputCloud(const PointCloudConstPtr& cloud,
                     const IndicesConstPtr& indices = IndicesConstPtr()) override {
    bool whole = !indices || indices->size() == input_->size();
    for (std::size_t i = 0; whole && indices && i < indices->size(); ++i) {
      whole = (*indices)[i] == static_cast<pcl::index_t>(i);
    }
    if (cloud != input_ || !whole) {
      throw std::logic_error("CachedNeighbourhoods serves only the whole cloud it was built on");
    }
    // Nothing to store: the cache is shared by threads and never changes after construction.
  }

 private:
  CachedNeighbourhoods(const PointCloudXYZ::Ptr& cloud,
                       const pcl::search::KdTree<pcl::PointXYZ>::Ptr& tree, double radius)
      : pcl::search::Search<pcl::PointXYZ>("CachedNeighbourhoods", false),
        tree_(tree),
        radius_(radius) {
    input_ = cloud;
    // Every point, in order (what clustering checks the search method was given).
    auto all = std::make_shared<pcl::Indices>(cloud->size());
    std::iota(all->begin(), all->end(), 0);
    indices_ = all;
  }

  pcl::search::KdTree<pcl::PointXYZ>::Ptr tree_;
  double radius_;
  std::vector<std::size_t> offsets_;
  pcl::Indices neighbours_;
  std::vector<float> sqr_distances_;
};

pcl::search::Search<pcl::PointXYZ>::Ptr radius_search_method(const Cloud::Impl& cloud,
                                                             double radius) {
  if (cloud.neighbourhoods && radius <= cloud.neighbourhoods->radius()) {
    // Searches are const and the cache is never modified after construction.
    return std::const_pointer_cast<CachedNeighbourhoods>(cloud.neighbourhoods);
  }
  return cloud.tree;
}

// At most this many cached neighbours (8 bytes each); beyond it the kd-tree answers alone.
constexpr std::size_t kMaxCachedNeighbours = std::size_t{16} << 20;

std::unique_ptr<Cloud> upload_cloud_with_neighbourhoods(rust::Slice<const float> xyz,
                                                        float radius, std::uint32_t threads) {
  check_positive(radius, "neighbourhood radius");
  auto impl = new_cloud(xyz, "upload_cloud_with_neighbourhoods");
  impl->neighbourhoods =
      CachedNeighbourhoods::build(impl->points, impl->tree, radius, kMaxCachedNeighbours,
                                  threads == 0 ? std::thread::hardware_concurrency() : threads);
  return std::make_unique<Cloud>(std::move(impl));
}

std::size_t cloud_len(const Cloud& cloud) { return cloud.size(); }

double cloud_neighbourhood_radius(const Cloud& cloud) {
  const auto& cache = cloud.impl().neighbourhoods;
  return cache ? cache->radius() : 0.0;
}

rust::Vec<float> nearest_sq_distances(const Cloud& cloud, rust::Slice<const float> query_xyz) {
  const auto query = to_cloud(query_xyz, "nearest_sq_distances query", true);
  const auto& tree = *cloud.impl().tree;
  rust::Vec<float> out;
  out.reserve(query->size());
  pcl::Indices idx(1);
  std::vector<float> d2(1);
  for (const auto& p : query->points) {
    if (tree.nearestKSearch(p, 1, idx, d2) != 1) {
      throw std::runtime_error("nearest_sq_distances: kd-tree returned no neighbour");
    }
    out.push_back(d2[0]);
  }
  return out;
}

}  // namespace binpick
