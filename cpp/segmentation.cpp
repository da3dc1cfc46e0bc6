// Euclidean clustering and supporting-plane fit (pcl_segmentation, pcl_sample_consensus).
#include <pcl/ModelCoefficients.h>
#include <pcl/segmentation/extract_clusters.h>
#include <pcl/segmentation/sac_segmentation.h>

#include <algorithm>

#include "binpick-pcl/src/ffi.rs.h"
#include "internal.h"

namespace binpick {

// pcl::EuclideanClusterExtraction (thesis 3.4.1.3) on an uploaded cloud, reusing its kd-tree.
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
  ec.setSearchMethod(c.tree);
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

// pcl::SACSegmentation, RANSAC plane with optimised coefficients (deterministic: PCL seeds
// its generator with 12345). `found` is false when PCL finds no plane.
PlaneFit segment_plane(rust::Slice<const float> xyz, float distance_threshold,
                       std::uint32_t max_iterations) {
  check_positive(distance_threshold, "plane distance threshold");
  if (max_iterations == 0) fail("plane fit needs at least one RANSAC iteration");
  const auto cloud = to_cloud(xyz, "segment_plane");
  if (cloud->size() < 3) fail("segment_plane: needs at least 3 points, got ", cloud->size());
  pcl::SACSegmentation<pcl::PointXYZ> seg;
  seg.setOptimizeCoefficients(true);
  seg.setModelType(pcl::SACMODEL_PLANE);
  seg.setMethodType(pcl::SAC_RANSAC);
  seg.setDistanceThreshold(distance_threshold);
  seg.setMaxIterations(static_cast<int>(max_iterations));
  seg.setInputCloud(cloud);
  pcl::PointIndices inliers;
  pcl::ModelCoefficients coefficients;
  seg.segment(inliers, coefficients);
  PlaneFit out;
  out.found = !inliers.indices.empty() && coefficients.values.size() == 4;
  if (out.found) {
    for (int i = 0; i < 4; ++i) out.coefficients[i] = coefficients.values[i];
    for (auto i : inliers.indices) out.inliers.push_back(static_cast<std::uint32_t>(i));
  }
  return out;
}

}  // namespace binpick
