// Helpers shared by the bridge's translation units (not seen by Rust or cxx).
#pragma once

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/sample_consensus/sac_model_plane.h>
#include <pcl/search/kdtree.h>

#include <functional>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "binpick_pcl.h"

// Build time: PCL_NO_PRECOMPILE (build.rs) compiles every PCL class a translation unit uses in
// that unit. The classes used in several are compiled once, explicitly, and declared extern in
// the others (same source, same flags: the same code). Every unit builds kd-trees; PCL's and
// FLANN's kd-tree classes are compiled in common.cpp (flann::Index's constructor alone
// instantiates all of FLANN's index types; LshIndex, for binary descriptors only, does not
// compile for floats and stays implicit).
#define BINPICK_SEARCH_TEMPLATES(X)                                  \
  X(class flann::Index<flann::L2_Simple<float>>)                     \
  X(class flann::KDTreeSingleIndex<flann::L2_Simple<float>>)         \
  X(class flann::KDTreeIndex<flann::L2_Simple<float>>)               \
  X(class flann::KMeansIndex<flann::L2_Simple<float>>)               \
  X(class flann::CompositeIndex<flann::L2_Simple<float>>)            \
  X(class flann::AutotunedIndex<flann::L2_Simple<float>>)            \
  X(class flann::HierarchicalClusteringIndex<flann::L2_Simple<float>>) \
  X(class flann::LinearIndex<flann::L2_Simple<float>>)               \
  X(class pcl::KdTreeFLANN<pcl::PointXYZ>)                           \
  X(class pcl::KdTreeFLANN<pcl::FPFHSignature33>)                    \
  X(class pcl::search::KdTree<pcl::PointXYZ>)                        \
  X(class pcl::search::KdTree<pcl::FPFHSignature33>)
#define BINPICK_EXTERN_TEMPLATE(...) extern template __VA_ARGS__;
#define BINPICK_INSTANTIATE_TEMPLATE(...) template __VA_ARGS__;
BINPICK_SEARCH_TEMPLATES(BINPICK_EXTERN_TEMPLATE)

// The classes the reference pipeline shares with one module's translation unit, compiled in
// that unit (BINPICK_INSTANTIATE_TEMPLATE) and declared extern in the pipeline. Expanded only
// where the module's PCL headers are included.
#define BINPICK_FEATURES_TEMPLATES(X)                                         \
  X(class pcl::Feature<pcl::PointXYZ, pcl::Normal>)                           \
  X(class pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal>)                  \
  X(class pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal>)               \
  X(class pcl::Feature<pcl::PointXYZ, pcl::FPFHSignature33>)                  \
  X(class pcl::FeatureFromNormals<pcl::PointXYZ, pcl::Normal, pcl::FPFHSignature33>) \
  X(class pcl::FPFHEstimation<pcl::PointXYZ, pcl::Normal, pcl::FPFHSignature33>) \
  X(class pcl::FPFHEstimationOMP<pcl::PointXYZ, pcl::Normal, pcl::FPFHSignature33>)
#define BINPICK_FILTERS_TEMPLATES(X)            \
  X(class pcl::Filter<pcl::PointXYZ>)           \
  X(class pcl::UniformSampling<pcl::PointXYZ>)  \
  X(class pcl::VoxelGrid<pcl::PointXYZ>)
#define BINPICK_SEGMENTATION_TEMPLATES(X) \
  X(class pcl::EuclideanClusterExtraction<pcl::PointXYZ>)
#define BINPICK_REGISTRATION_TEMPLATES(X)                                                  \
  X(class pcl::registration::CorrespondenceEstimationBase<pcl::FPFHSignature33,            \
                                                          pcl::FPFHSignature33, float>)    \
  X(class pcl::registration::CorrespondenceEstimation<pcl::FPFHSignature33,                \
                                                      pcl::FPFHSignature33, float>)        \
  X(class pcl::registration::CorrespondenceEstimationBase<pcl::PointXYZ, pcl::PointXYZ,    \
                                                          double>)                         \
  X(class pcl::registration::CorrespondenceEstimation<pcl::PointXYZ, pcl::PointXYZ, double>) \
  X(class pcl::registration::CorrespondenceRejectorSampleConsensus<pcl::PointXYZ>)         \
  X(class pcl::SampleConsensusModelRegistration<pcl::PointXYZ>)                            \
  X(class pcl::RandomSampleConsensus<pcl::PointXYZ>)                                       \
  X(class pcl::Registration<pcl::PointXYZ, pcl::PointXYZ, double>)                         \
  X(class pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ, double>)                \
  X(class pcl::registration::TransformationEstimationSVD<pcl::PointXYZ, pcl::PointXYZ, double>)

namespace binpick {

using PointCloudXYZ = pcl::PointCloud<pcl::PointXYZ>;

// A FLANN index answering many nearest-neighbour queries in one call (registration.cpp).
struct BatchIndex;

// Every point's neighbours within a fixed radius, found once with the cloud's kd-tree and
// served to PCL's estimators at any radius up to it (common.cpp).
class CachedNeighbourhoods;

struct Cloud::Impl {
  PointCloudXYZ::Ptr points;
  pcl::search::KdTree<pcl::PointXYZ>::Ptr tree;
  // Optional (upload_cloud_with_neighbourhoods): the search method for radius searches of
  // the cloud's own points up to its radius; null when not cached.
  std::shared_ptr<const CachedNeighbourhoods> neighbourhoods;
  // Built on first use by ICP (std::call_once keeps a shared Cloud thread-safe).
  mutable std::once_flag batch_once;
  mutable std::shared_ptr<const BatchIndex> batch;
};

// The search method for radius searches of the cloud's own points within `radius`: the
// neighbourhood cache when it covers the radius, else the kd-tree. Same answers either way.
pcl::search::Search<pcl::PointXYZ>::Ptr radius_search_method(const Cloud::Impl& cloud,
                                                             double radius);

// The cloud's batch index, built on first call.
const BatchIndex& batch_index(const Cloud::Impl& cloud);

// Throws std::invalid_argument with a message built from the arguments.
template <typename... Args>
[[noreturn]] void fail(const Args&... args) {
  std::ostringstream msg;
  (msg << ... << args);
  throw std::invalid_argument(msg.str());
}

// Converts a flat [x0 y0 z0 x1 ...] slice into a dense PCL cloud. Rejects slices whose
// length is not a multiple of 3, empty slices (unless allowed) and non-finite coordinates:
// PCL's kd-trees and estimators silently misbehave on those.
PointCloudXYZ::Ptr to_cloud(rust::Slice<const float> xyz, const char* what,
                            bool allow_empty = false);

// Indices into a cloud of `n` points, each checked to be in range.
pcl::Indices to_indices(rust::Slice<const std::uint32_t> idx, std::size_t n, const char* what);

// Builds the kd-tree PCL's own estimators build by default (unsorted radius results).
pcl::search::KdTree<pcl::PointXYZ>::Ptr make_tree(const PointCloudXYZ::Ptr& cloud);

// Refuses grids whose integer voxel indices would overflow PCL's 32-bit arithmetic
// (VoxelGrid then returns its input unchanged; UniformSampling silently aliases leaves).
void check_grid(const PointCloudXYZ& cloud, float leaf, const char* what);

void check_positive(double value, const char* name);

// pcl::SACSegmentation<PointXYZ>::segment (PCL 1.13) for SACMODEL_PLANE, SAC_RANSAC and
// optimised coefficients, on `model` (over all the cloud's points, random = false): PCL's
// RandomSampleConsensus with SACSegmentation's defaults (probability 0.99, PCL's thread
// count), the refined coefficients and the inliers within `distance_threshold` of them
// (segmentation.cpp). False, with both outputs empty, when RANSAC finds no plane.
// `after_search` runs once RANSAC's search ends (it may throw). Written out because
// instantiating SACSegmentation compiles every model and method PCL has (its initSACModel and
// initSAC switches: minutes of build time) for this one path.
bool fit_plane_as_sac_segmentation(const pcl::SampleConsensusModelPlane<pcl::PointXYZ>::Ptr& model,
                                   float distance_threshold, std::uint32_t max_iterations,
                                   pcl::Indices& inliers, std::vector<float>& coefficients,
                                   const std::function<void()>& after_search = {});

// fit_plane_as_sac_segmentation over PCL's own SampleConsensusModelPlane on all of `cloud`.
bool fit_plane_pcl(const PointCloudXYZ::Ptr& cloud, float distance_threshold,
                   std::uint32_t max_iterations, pcl::Indices& inliers,
                   std::vector<float>& coefficients);

// Finds PCL's pcl::computePairFeatures in libpcl_features (features.cpp), or throws saying why.
// Called before any FPFH computation, outside OpenMP regions.
void require_pair_features();

// Throws binpick's interruption marker when the Rust caller asked the running call to stop
// (time budget or cancellation: `binpick_pcl::set_interrupt` on the calling thread). Long
// calls poll it between chunks whose answers do not depend on where they are cut: an
// interrupted call's answer is thrown away, a finished one is the same as without polling.
// Only ever called on the calling thread and outside OpenMP regions (an exception must not
// leave one: PCL's RANSAC loop is one even when it runs on one thread).
void check_interrupt(const char* where);

// Throws the interruption marker unconditionally (for loops that noticed the request inside
// an OpenMP region, where they cannot throw, and stopped early).
[[noreturn]] void throw_interrupted(const char* where);

// The message prefix `check_interrupt` throws with (src/lib.rs maps it to Error::Interrupted).
inline constexpr const char* kInterruptedMarker = "binpick-interrupted: ";

// pcl::UniformSampling at `leaf` (filters.cpp): the input indices of the kept points, ascending.
// Shared by the bridge's uniform_sampling and the reference pipeline.
std::vector<std::uint32_t> uniform_sampling_indices(const PointCloudXYZ::Ptr& cloud, float leaf);

// pcl::VoxelGrid at `leaf` (filters.cpp): one centroid per occupied cell. `what` names the
// caller in errors. A grid too large for PCL's 32-bit voxel index is filtered in tiles.
PointCloudXYZ voxel_grid_points(const PointCloudXYZ::Ptr& cloud, float leaf, const char* what);

}  // namespace binpick
