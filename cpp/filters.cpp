// Down-sampling (pcl_filters): UniformSampling keypoints (thesis 3.2.3) and VoxelGrid.
#include <pcl/filters/uniform_sampling.h>
#include <pcl/filters/voxel_grid.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "binpick-pcl/src/ffi.rs.h"
#include "internal.h"

// The classes this module shares with the reference pipeline, compiled here once (internal.h).
BINPICK_FILTERS_TEMPLATES(BINPICK_INSTANTIATE_TEMPLATE)

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

namespace {

// The largest voxel count pcl::VoxelGrid indexes: it refuses (returns its input unchanged)
// a grid of more cells than a 32-bit int holds.
constexpr std::int64_t kMaxVoxels = std::numeric_limits<std::int32_t>::max();

// A cloud's voxel-index range per axis, computed as pcl::VoxelGrid does
// (floor(coordinate * (1 / leaf)) in float).
struct CellBounds {
  std::array<std::int64_t, 3> min{}, max{};
  std::int64_t span(int axis) const { return max[axis] - min[axis] + 1; }
  std::int64_t cells() const {
    std::int64_t c = 1;
    for (int a = 0; a < 3; ++a) {
      if (c > kMaxVoxels) return kMaxVoxels + 1;  // avoids overflowing int64
      c *= span(a);
    }
    return c;
  }
};

std::int64_t cell_of(float coordinate, float inverse_leaf) {
  // Clamped inside int64 (anything beyond int32 is refused by the caller anyway).
  constexpr float kLimit = 4.0e18f;
  return static_cast<std::int64_t>(std::clamp(std::floor(coordinate * inverse_leaf), -kLimit, kLimit));
}

CellBounds cell_bounds(const PointCloudXYZ& cloud, float inverse_leaf) {
  CellBounds b;
  b.min.fill(std::numeric_limits<std::int64_t>::max());
  b.max.fill(std::numeric_limits<std::int64_t>::min());
  for (const auto& p : cloud.points) {
    const std::array<float, 3> xyz{p.x, p.y, p.z};
    for (int a = 0; a < 3; ++a) {
      const auto c = cell_of(xyz[a], inverse_leaf);
      b.min[a] = std::min(b.min[a], c);
      b.max[a] = std::max(b.max[a], c);
    }
  }
  return b;
}

void plain_voxel_grid(const PointCloudXYZ::Ptr& cloud, float leaf, PointCloudXYZ& out) {
  pcl::VoxelGrid<pcl::PointXYZ> vg;
  vg.setInputCloud(cloud);
  vg.setLeafSize(leaf, leaf, leaf);
  PointCloudXYZ filtered;
  vg.filter(filtered);
  out.insert(out.end(), filtered.begin(), filtered.end());
}

// pcl::VoxelGrid on a cloud whose grid may exceed PCL's voxel index: a grid that fits is one
// PCL call (the plain filter, bit for bit); one that does not is split in two along the most
// significant axis of PCL's voxel order (z, then y, then x) at a voxel boundary, and each half
// filtered the same way. Every voxel lies in exactly one tile, and the tiles are concatenated
// in PCL's output order (by z cell, then y, then x), so the result is the cells PCL would
// compute with a wider index.
void tiled_voxel_grid(const PointCloudXYZ::Ptr& cloud, float leaf, float inverse_leaf,
                      PointCloudXYZ& out) {
  if (cloud->empty()) return;  // (never: both halves of a split hold a point)
  const CellBounds b = cell_bounds(*cloud, inverse_leaf);
  if (b.cells() <= kMaxVoxels) {
    plain_voxel_grid(cloud, leaf, out);
    return;
  }
  check_interrupt("voxel grid tile");
  const int axis = b.span(2) > 1 ? 2 : b.span(1) > 1 ? 1 : 0;
  const std::int64_t mid = b.min[axis] + (b.max[axis] - b.min[axis]) / 2;
  PointCloudXYZ::Ptr low(new PointCloudXYZ), high(new PointCloudXYZ);
  for (const auto& p : cloud->points) {
    const float v = axis == 2 ? p.z : axis == 1 ? p.y : p.x;
    (cell_of(v, inverse_leaf) <= mid ? low : high)->push_back(p);
  }
  cloud->clear();  // the halves hold the points now
  tiled_voxel_grid(low, leaf, inverse_leaf, out);
  tiled_voxel_grid(high, leaf, inverse_leaf, out);
}

}  // namespace

PointCloudXYZ voxel_grid_points(const PointCloudXYZ::Ptr& cloud, float leaf, const char* what) {
  check_positive(leaf, "leaf size");
  const float inverse_leaf = 1.0f / leaf;  // as pcl::VoxelGrid
  const CellBounds b = cell_bounds(*cloud, inverse_leaf);
  for (int a = 0; a < 3; ++a) {
    // PCL stores voxel coordinates as int; beyond that its index silently wraps.
    if (b.min[a] < std::numeric_limits<std::int32_t>::min() ||
        b.max[a] > std::numeric_limits<std::int32_t>::max()) {
      fail(what, ": a coordinate of ", (b.min[a] < 0 ? b.min[a] : b.max[a]) * static_cast<double>(leaf),
           " along axis ", a, " is beyond PCL's 32-bit voxel coordinates for a leaf of ", leaf);
    }
  }
  PointCloudXYZ out;
  if (b.cells() <= kMaxVoxels) {
    plain_voxel_grid(cloud, leaf, out);
  } else {
    PointCloudXYZ::Ptr copy(new PointCloudXYZ(*cloud));
    tiled_voxel_grid(copy, leaf, inverse_leaf, out);
  }
  out.width = static_cast<std::uint32_t>(out.size());
  out.height = 1;
  out.is_dense = true;
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
