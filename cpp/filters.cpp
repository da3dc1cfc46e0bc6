// Down-sampling (pcl_filters): UniformSampling keypoints (thesis 3.2.3) and VoxelGrid.
#include <pcl/filters/uniform_sampling.h>
#include <pcl/filters/voxel_grid.h>

#include <algorithm>
#include <vector>

#include "binpick-pcl/src/ffi.rs.h"
#include "internal.h"

namespace binpick {

// pcl::UniformSampling keeps, in every leaf x leaf x leaf cell, the input point closest to the
// cell centre, so keypoints are a subset of the input (unlike voxel centroids). PCL emits them
// in hash-map order; we return their input indices sorted ascending, which is deterministic
// and lets callers keep per-point data (normals, instance labels) aligned.
std::vector<std::uint32_t> uniform_sampling_indices(const PointCloudXYZ::Ptr& cloud, float leaf) {
  check_grid(*cloud, leaf, "uniform_sampling");
  pcl::UniformSampling<pcl::PointXYZ> us(/*extract_removed_indices=*/true);
  us.setInputCloud(cloud);
  us.setRadiusSearch(leaf);
  PointCloudXYZ kept;
  us.filter(kept);
  std::vector<bool> is_removed(cloud->size(), false);
  for (auto i : *us.getRemovedIndices()) is_removed[static_cast<std::size_t>(i)] = true;
  std::vector<std::uint32_t> out;
  out.reserve(kept.size());
  for (std::size_t i = 0; i < cloud->size(); ++i) {
    if (!is_removed[i]) out.push_back(static_cast<std::uint32_t>(i));
  }
  if (out.size() != kept.size()) {
    throw std::runtime_error("uniform_sampling: PCL kept " + std::to_string(kept.size()) +
                             " points but removed-index bookkeeping leaves " +
                             std::to_string(out.size()));
  }
  return out;
}

rust::Vec<std::uint32_t> uniform_sampling(rust::Slice<const float> xyz, float leaf) {
  const auto idx = uniform_sampling_indices(to_cloud(xyz, "uniform_sampling"), leaf);
  rust::Vec<std::uint32_t> out;
  out.reserve(idx.size());
  for (auto i : idx) out.push_back(i);
  return out;
}

PointCloudXYZ voxel_grid_points(const PointCloudXYZ::Ptr& cloud, float leaf, const char* what) {
  check_grid(*cloud, leaf, what);
  pcl::VoxelGrid<pcl::PointXYZ> vg;
  vg.setInputCloud(cloud);
  vg.setLeafSize(leaf, leaf, leaf);
  PointCloudXYZ out;
  vg.filter(out);
  return out;
}

// pcl::VoxelGrid: one centroid per occupied leaf (points are new, not input points).
rust::Vec<float> voxel_grid(rust::Slice<const float> xyz, float leaf) {
  const auto filtered = voxel_grid_points(to_cloud(xyz, "voxel_grid"), leaf, "voxel_grid");
  rust::Vec<float> out;
  out.reserve(filtered.size() * 3);
  for (const auto& p : filtered.points) {
    out.push_back(p.x);
    out.push_back(p.y);
    out.push_back(p.z);
  }
  return out;
}

}  // namespace binpick
