// Cloud upload, shared kd-tree queries and input validation (pcl_common, pcl_search).
#include <pcl/common/common.h>
#include <pcl/console/print.h>

#include <cmath>
#include <cstdint>
#include <limits>

#include "binpick-pcl/src/ffi.rs.h"
#include "internal.h"

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

std::unique_ptr<Cloud> upload_cloud(rust::Slice<const float> xyz) {
  auto impl = std::make_unique<Cloud::Impl>();
  impl->points = to_cloud(xyz, "upload_cloud");
  impl->tree = make_tree(impl->points);
  return std::make_unique<Cloud>(std::move(impl));
}

std::size_t cloud_len(const Cloud& cloud) { return cloud.size(); }

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
