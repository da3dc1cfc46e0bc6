// Thin C++ side of the binpick <-> PCL bridge.
//
// Every function takes plain data from Rust (flat xyz slices, indices) and returns plain data
// (rust::Vec, shared structs declared in src/ffi.rs). PCL types stay inside the .cpp files.
// Every entry point is declared `Result<...>` on the Rust side, so any exception thrown here
// (std::invalid_argument for bad input, std::runtime_error for PCL failures) becomes a Rust
// error instead of crossing the FFI boundary.
#pragma once

#include <cstdint>
#include <memory>

#include "rust/cxx.h"

namespace binpick {

struct Correspondence;
struct SacResult;
struct IcpParams;
struct IcpResult;
struct PlaneFit;
struct Clusters;
struct Features;
struct Transform;
struct ReferenceParams;
struct ReferenceResult;

// A cloud uploaded once and reused by many calls: owns the pcl::PointCloud<PointXYZ> and its
// kd-tree (pcl::search::KdTree, FLANN). Immutable after construction, so it can be shared by
// several threads (FLANN searches are const).
class Cloud {
 public:
  struct Impl;
  explicit Cloud(std::unique_ptr<Impl> impl);
  ~Cloud();
  Cloud(const Cloud&) = delete;
  Cloud& operator=(const Cloud&) = delete;
  const Impl& impl() const { return *impl_; }
  std::size_t size() const;

 private:
  std::unique_ptr<Impl> impl_;
};

// --- common.cpp --------------------------------------------------------------------------
void set_pcl_verbosity(std::int32_t level);
std::unique_ptr<Cloud> upload_cloud(rust::Slice<const float> xyz);
std::unique_ptr<Cloud> upload_cloud_with_neighbourhoods(rust::Slice<const float> xyz,
                                                        float radius, std::uint32_t threads);
std::size_t cloud_len(const Cloud& cloud);
double cloud_neighbourhood_radius(const Cloud& cloud);
rust::Vec<float> nearest_sq_distances(const Cloud& cloud, rust::Slice<const float> query_xyz);

// --- filters.cpp (pcl_filters) -----------------------------------------------------------
rust::Vec<std::uint32_t> uniform_sampling(rust::Slice<const float> xyz, float leaf);
rust::Vec<float> voxel_grid(rust::Slice<const float> xyz, float leaf);

// --- features.cpp (pcl_features) ---------------------------------------------------------
rust::Vec<float> estimate_normals(rust::Slice<const float> xyz, float radius,
                                  rust::Slice<const float> viewpoint, std::uint32_t threads);
rust::Vec<float> estimate_normals_at(rust::Slice<const float> xyz,
                                     rust::Slice<const std::uint32_t> at, float radius,
                                     rust::Slice<const float> viewpoint, std::uint32_t threads);
rust::Vec<float> cloud_normals_at(const Cloud& cloud, rust::Slice<const std::uint32_t> at,
                                  float radius, rust::Slice<const float> viewpoint,
                                  std::uint32_t threads);
Features cloud_fpfh(const Cloud& surface, rust::Slice<const std::uint32_t> keypoints,
                    float feature_radius, float normal_radius, rust::Slice<const float> viewpoint,
                    std::uint32_t threads);

// --- segmentation.cpp (pcl_segmentation) -------------------------------------------------
Clusters euclidean_clusters(const Cloud& cloud, float tolerance, std::uint32_t min_size,
                            std::uint32_t max_size);
PlaneFit segment_plane(rust::Slice<const float> xyz, float distance_threshold,
                       std::uint32_t max_iterations, std::uint32_t threads);
PlaneFit segment_plane_pcl(rust::Slice<const float> xyz, float distance_threshold,
                           std::uint32_t max_iterations);
rust::Vec<std::uint64_t> plane_inlier_counts(rust::Slice<const float> xyz,
                                             rust::Slice<const float> planes,
                                             double distance_threshold);

// --- registration.cpp (pcl_registration) -------------------------------------------------
rust::Vec<Correspondence> match_features(rust::Slice<const float> source_features,
                                         rust::Slice<const float> target_features);
SacResult reject_sample_consensus(rust::Slice<const float> source_xyz,
                                  rust::Slice<const float> target_xyz,
                                  rust::Slice<const Correspondence> correspondences,
                                  float inlier_threshold, std::uint32_t max_iterations);
rust::Vec<SacResult> reject_sample_consensus_sweep(rust::Slice<const float> source_xyz,
                                                   rust::Slice<const float> target_xyz,
                                                   rust::Slice<const Correspondence> correspondences,
                                                   rust::Slice<const float> inlier_thresholds,
                                                   std::uint32_t max_iterations);
Transform estimate_svd(rust::Slice<const float> source_xyz, rust::Slice<const float> target_xyz,
                       rust::Slice<const Correspondence> correspondences);
IcpResult icp_align(const Cloud& target, rust::Slice<const float> source_xyz,
                    const IcpParams& params);

// --- reference/pipeline.cpp (OpenMP; thesis Algorithms 1 and 2 in one call) ---------------
ReferenceResult reference_recognize(rust::Slice<const float> model_xyz,
                                    rust::Slice<const float> scene_xyz,
                                    const ReferenceParams& params);

}  // namespace binpick
