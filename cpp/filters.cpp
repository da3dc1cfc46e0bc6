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
rust::Vec<std::uint32_t> uniform_sampling(rust::Slice<const float> xyz, float leaf) {
  const auto cloud = to_cloud(xyz, "uniform_sampling");
  check_grid(*cloud, leaf, "uniform_sampling");
  pcl::UniformSampling<pcl::PointXYZ> us(/*extract_removed_indices=*/true);
  us.setInputCloud(cloud);
  us.setRadiusSearch(leaf);
  PointCloudXYZ kept;
  us.filter(kept);
  const auto& removed = *us.getRemovedIndices();
  std::vector<bool> is_removed(cloud->size(), false);
  for (auto i : removed) is_removed[static_cast<std::size_t>(i)] = true;
  rust::Vec<std::uint32_t> out;
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

// pcl::VoxelGrid: one centroid per occupied leaf (points are new, not input points).
rust::Vec<float> voxel_grid(rust::Slice<const float> xyz, float leaf) {
  const auto cloud = to_cloud(xyz, "voxel_grid");
  check_grid(*cloud, leaf, "voxel_grid");
  pcl::VoxelGrid<pcl::PointXYZ> vg;
  vg.setInputCloud(cloud);
  vg.setLeafSize(leaf, leaf, leaf);
  PointCloudXYZ out_cloud;
  vg.filter(out_cloud);
  rust::Vec<float> out;
  out.reserve(out_cloud.size() * 3);
  for (const auto& p : out_cloud.points) {
    out.push_back(p.x);
    out.push_back(p.y);
    out.push_back(p.z);
  }
  return out;
}

}  // namespace binpick
