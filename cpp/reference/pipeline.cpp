// Reference pipeline: thesis Algorithms 1 and 2 (S. Squizzato, "Robot bin picking: 3D pose
// retrieval based on Point Cloud Library", chapters 3-4) written directly in C++ against PCL,
// the way the thesis describes them, in one call: model xyz + scene xyz + parameters ->
// detections, per-cluster outcomes, preprocessing counts and stage timings.
//
// It computes what binpick's Rust pipeline computes with `Params { thesis_strict: true }`, step
// for step (same PCL classes, same settings, same order of points, same tie-breaking), but
// keeps the thesis's structure instead of binpick's:
//
//   * the model's keypoints and FPFH descriptors are recomputed inside the loop over clusters
//     (Algorithm 1 step 1a-b; binpick computes them once per model);
//   * every PCL stage builds its own kd-tree, and so does every validation score (3.1.1.3:
//     "Construction of the KD-Tree: O(n log n)"); binpick uploads the scene once and shares
//     its trees;
//   * clusters run in an OpenMP `parallel for` (4.4), and inside each cluster PCL's
//     NormalEstimationOMP / FPFHEstimationOMP keep their default thread count;
//   * ICP uses PCL's default correspondence estimation (one kd-tree query per point).
//
// Everything binpick adds to the thesis for determinism (sorted uniform keypoints, clusters
// ordered by first index, support-plane removal, the Euclidean tie-break when ICP leaves the
// percent of outliers unchanged) is reproduced exactly so the answers can be compared. Every failure is
// an exception, which cxx turns into a Rust error; nothing escapes the OpenMP region.
#include <omp.h>

#include <pcl/correspondence.h>
#include <pcl/features/fpfh_omp.h>
#include <pcl/features/normal_3d_omp.h>
#include <pcl/filters/uniform_sampling.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/registration/correspondence_estimation.h>
#include <pcl/registration/correspondence_rejection_sample_consensus.h>
#include <pcl/registration/icp.h>
#include <pcl/registration/transformation_estimation_svd.h>
#include <pcl/segmentation/extract_clusters.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <numeric>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "binpick-pcl/src/ffi.rs.h"
#include "internal.h"

// The PCL classes the bridge's modules compile (internal.h): declared here, not compiled again.
BINPICK_FEATURES_TEMPLATES(BINPICK_EXTERN_TEMPLATE)
BINPICK_FILTERS_TEMPLATES(BINPICK_EXTERN_TEMPLATE)
BINPICK_SEGMENTATION_TEMPLATES(BINPICK_EXTERN_TEMPLATE)
BINPICK_REGISTRATION_TEMPLATES(BINPICK_EXTERN_TEMPLATE)

namespace binpick {
namespace {

using Clock = std::chrono::steady_clock;
using FeatureCloud = pcl::PointCloud<pcl::FPFHSignature33>;
using Normals = pcl::PointCloud<pcl::Normal>;

// Smallest model the pipeline works with, in voxelised points (as binpick's model.rs).
constexpr std::size_t kMinModelPoints = 20;
// Tolerance on det(R) = +1 for PCL's transforms (binpick_pcl::DET_TOLERANCE).
constexpr double kDetTolerance = 1e-3;
// A row-major matrix is a rigid transform within this (binpick_cloud::pose_from_row_major).
constexpr double kRigidTolerance = 1e-4;

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// ---------------------------------------------------------------------------------------
// Clouds

// Finishes a cloud built point by point the way binpick's upload does (unorganised, dense).
void finish(PointCloudXYZ& c) {
  c.width = static_cast<std::uint32_t>(c.size());
  c.height = 1;
  c.is_dense = true;
}

PointCloudXYZ::Ptr from_xyz(rust::Slice<const float> xyz, const char* what) {
  if (xyz.size() % 3 != 0) fail(what, ": ", xyz.size(), " floats is not a whole number of xyz points");
  const std::size_t n = xyz.size() / 3;
  if (n == 0) fail(what, ": the cloud is empty");
  if (n > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max())) {
    fail(what, ": ", n, " points exceed PCL's 32-bit index range");
  }
  PointCloudXYZ::Ptr cloud(new PointCloudXYZ);
  cloud->resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    const float x = xyz[3 * i], y = xyz[3 * i + 1], z = xyz[3 * i + 2];
    if (!(std::isfinite(x) && std::isfinite(y) && std::isfinite(z))) {
      fail(what, ": point ", i, " has a non-finite coordinate");
    }
    (*cloud)[i] = pcl::PointXYZ(x, y, z);
  }
  finish(*cloud);
  return cloud;
}

template <typename Index>
PointCloudXYZ::Ptr subset(const PointCloudXYZ& in, const std::vector<Index>& idx) {
  PointCloudXYZ::Ptr out(new PointCloudXYZ);
  out->resize(idx.size());
  for (std::size_t k = 0; k < idx.size(); ++k) (*out)[k] = in[static_cast<std::size_t>(idx[k])];
  finish(*out);
  return out;
}

// Keypoints (thesis 3.2.3) come from uniform_sampling_indices (internal.h), the bridge's own
// pcl::UniformSampling wrapper, so both engines keep the same points in the same order.

// pcl::VoxelGrid at `leaf` (thesis 4.3 #1): one centroid per occupied cell.
PointCloudXYZ::Ptr voxel_grid(const PointCloudXYZ::Ptr& cloud, float leaf, const char* what) {
  const PointCloudXYZ filtered = voxel_grid_points(cloud, leaf, what);
  PointCloudXYZ::Ptr out(new PointCloudXYZ);
  out->points.assign(filtered.points.begin(), filtered.points.end());
  finish(*out);
  return out;
}

// ---------------------------------------------------------------------------------------
// Features (thesis 3.3.2)

// FPFH descriptors of one radius; only keypoints with a defined descriptor are kept and
// `keypoint[i]` is the keypoint index of descriptor i.
struct RadiusDescriptors {
  FeatureCloud::Ptr descriptors;
  std::vector<std::uint32_t> keypoint;
};

// Normals on the whole surface at `normal_radius` (NormalEstimationOMP), then FPFH at the
// keypoints (FPFHEstimationOMP), both with PCL's default thread count and their own kd-trees.
// A keypoint whose normal or histogram is undefined is dropped, as the bridge's cloud_fpfh
// marks it invalid.
RadiusDescriptors fpfh(const PointCloudXYZ::Ptr& surface, const pcl::IndicesPtr& keypoints,
                       double radius, double normal_factor, const std::array<double, 3>& vp) {
  const float feature_radius = static_cast<float>(radius);
  const float normal_radius = static_cast<float>(radius * normal_factor);
  check_positive(feature_radius, "FPFH radius");
  check_positive(normal_radius, "normal radius");
  if (keypoints->empty()) fail("cloud_fpfh: no keypoints");
  require_pair_features();

  pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal> ne;
  ne.setInputCloud(surface);
  ne.setRadiusSearch(normal_radius);
  ne.setViewPoint(static_cast<float>(vp[0]), static_cast<float>(vp[1]),
                  static_cast<float>(vp[2]));
  Normals::Ptr normals(new Normals);
  ne.compute(*normals);
  if (normals->size() != surface->size()) {
    throw std::runtime_error("NormalEstimationOMP failed (see PCL's message above)");
  }

  pcl::FPFHEstimationOMP<pcl::PointXYZ, pcl::Normal, pcl::FPFHSignature33> est;
  est.setInputCloud(surface);
  est.setIndices(keypoints);
  est.setInputNormals(normals);
  est.setRadiusSearch(feature_radius);
  FeatureCloud all;
  est.compute(all);
  if (all.size() != keypoints->size()) {
    throw std::runtime_error("FPFHEstimationOMP failed (see PCL's message above)");
  }

  RadiusDescriptors out;
  out.descriptors.reset(new FeatureCloud);
  for (std::size_t k = 0; k < all.size(); ++k) {
    const auto& h = all[k].histogram;
    const auto& n = (*normals)[static_cast<std::size_t>((*keypoints)[k])];
    bool ok = std::isfinite(n.normal_x) && std::isfinite(n.normal_y) && std::isfinite(n.normal_z);
    for (int d = 0; d < 33; ++d) ok = ok && std::isfinite(h[d]);
    if (ok) {
      out.descriptors->push_back(all[k]);
      out.keypoint.push_back(static_cast<std::uint32_t>(k));
    }
  }
  out.descriptors->width = static_cast<std::uint32_t>(out.descriptors->size());
  out.descriptors->height = 1;
  return out;
}

// Keypoints at the initial leaf of `cloud` (model or cluster) and their FPFH search surface:
// the keypoints themselves (feature_surface = keypoints) or the whole cloud.
struct KeypointSet {
  PointCloudXYZ::Ptr keypoints;
  PointCloudXYZ::Ptr surface;
  pcl::IndicesPtr surface_keypoints;
};

KeypointSet keypoint_set(const PointCloudXYZ::Ptr& cloud, const std::vector<std::uint32_t>& idx,
                         bool surface_is_cloud) {
  KeypointSet s;
  s.keypoints = subset(*cloud, idx);
  s.surface_keypoints.reset(new pcl::Indices);
  if (surface_is_cloud) {
    s.surface = cloud;
    for (auto i : idx) s.surface_keypoints->push_back(static_cast<pcl::index_t>(i));
  } else {
    s.surface = s.keypoints;
    for (std::size_t i = 0; i < idx.size(); ++i) {
      s.surface_keypoints->push_back(static_cast<pcl::index_t>(i));
    }
  }
  return s;
}

// pcl::registration::CorrespondenceEstimation in FPFH space (thesis 3.4.1), mapped back from
// descriptor indices to keypoint indices.
pcl::Correspondences match(const RadiusDescriptors& model, const RadiusDescriptors& cluster) {
  pcl::registration::CorrespondenceEstimation<pcl::FPFHSignature33, pcl::FPFHSignature33> est;
  est.setInputSource(model.descriptors);
  est.setInputTarget(cluster.descriptors);
  pcl::Correspondences corrs;
  est.determineCorrespondences(corrs);
  for (auto& c : corrs) {
    c.index_query = static_cast<pcl::index_t>(model.keypoint[static_cast<std::size_t>(c.index_query)]);
    c.index_match = static_cast<pcl::index_t>(cluster.keypoint[static_cast<std::size_t>(c.index_match)]);
  }
  return corrs;
}

// Algorithm 2 step 1b-iii: one set holding, for each model keypoint, its match with the
// smallest descriptor distance over all radii (the earlier radius on ties), ordered by model
// keypoint.
pcl::Correspondences merge_best(const std::vector<pcl::Correspondences>& sets,
                                std::size_t n_model) {
  std::vector<bool> have(n_model, false);
  std::vector<pcl::Correspondence> best(n_model);
  for (const auto& set : sets) {
    for (const auto& c : set) {
      const auto q = static_cast<std::size_t>(c.index_query);
      if (!have[q] || c.distance < best[q].distance) {
        best[q] = c;
        have[q] = true;
      }
    }
  }
  pcl::Correspondences out;
  for (std::size_t q = 0; q < n_model; ++q) {
    if (have[q]) out.push_back(best[q]);
  }
  return out;
}

// ---------------------------------------------------------------------------------------
// Poses and validation functions (thesis 3.1)

using Pose = Eigen::Matrix4d;

std::array<double, 16> row_major(const Pose& m) {
  std::array<double, 16> out{};
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) out[static_cast<std::size_t>(r * 4 + c)] = m(r, c);
  return out;
}

double rotation_det(const Pose& m) {
  const double a = m(0, 0), b = m(0, 1), c = m(0, 2);
  const double d = m(1, 0), e = m(1, 1), f = m(1, 2);
  const double g = m(2, 0), h = m(2, 1), i = m(2, 2);
  return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
}

// binpick_pcl's check: det(R) = +1 within 1e-3.
bool proper(const Pose& m) {
  const double det = rotation_det(m);
  return std::isfinite(det) && std::abs(det - 1.0) <= kDetTolerance;
}

// binpick_cloud's pose_from_row_major: finite, last row (0 0 0 1), R orthonormal with det +1.
bool rigid(const Pose& m) {
  if (!m.allFinite()) return false;
  const double last = std::abs(m(3, 0)) + std::abs(m(3, 1)) + std::abs(m(3, 2)) + std::abs(m(3, 3) - 1.0);
  if (last > 1e-9) return false;
  const Eigen::Matrix3d r = m.topLeftCorner<3, 3>();
  const double orthogonality = (r.transpose() * r - Eigen::Matrix3d::Identity()).norm();
  return !(orthogonality > kRigidTolerance || std::abs(r.determinant() - 1.0) > kRigidTolerance);
}

// A model point placed by `pose`, in double, then stored as float like every cloud.
pcl::PointXYZ moved(const Pose& m, const pcl::PointXYZ& p) {
  const double x = p.x, y = p.y, z = p.z;
  return pcl::PointXYZ(static_cast<float>(m(0, 0) * x + m(0, 1) * y + m(0, 2) * z + m(0, 3)),
                       static_cast<float>(m(1, 0) * x + m(1, 1) * y + m(1, 2) * z + m(1, 3)),
                       static_cast<float>(m(2, 0) * x + m(2, 1) * y + m(2, 2) * z + m(2, 3)));
}

// Squared distance from every placed model point to its nearest world point, through a
// kd-tree (pcl::KdTreeFLANN) built for this call (thesis 3.1.1.3).
template <typename Fn>
void for_each_nearest(const PointCloudXYZ::Ptr& world, const PointCloudXYZ& model, const Pose& pose,
                      Fn&& fn) {
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setInputCloud(world);
  pcl::Indices idx(1);
  std::vector<float> d2(1);
  for (const auto& p : model.points) {
    if (tree.nearestKSearch(moved(pose, p), 1, idx, d2) != 1) {
      throw std::runtime_error("validation: kd-tree returned no neighbour");
    }
    fn(d2[0]);
  }
}

// Euclidean distance validation (3.1.1): mean squared nearest distance, mm^2.
double euclidean_score(const PointCloudXYZ::Ptr& world, const PointCloudXYZ& model, const Pose& pose) {
  if (model.empty()) return std::numeric_limits<double>::max();
  double sum = 0.0;
  for_each_nearest(world, model, pose, [&sum](float d2) { sum += static_cast<double>(d2); });
  return sum / static_cast<double>(model.size());
}

// Percent of outliers validation (3.1.2): share of points farther than `distance`, percent.
double outlier_percent(const PointCloudXYZ::Ptr& world, const PointCloudXYZ& model, const Pose& pose,
                       double distance) {
  if (model.empty()) return 100.0;
  const float limit = static_cast<float>(distance * distance);
  std::size_t outliers = 0;
  for_each_nearest(world, model, pose, [&](float d2) {
    if (d2 > limit) ++outliers;
  });
  return 100.0 * static_cast<double>(outliers) / static_cast<double>(model.size());
}

// ---------------------------------------------------------------------------------------
// Supporting-surface removal (binpick's scene.rs; not in the thesis)

// For points on a plane, whether each belongs to a connected patch of at least `min_points`:
// a 2-D grid in the plane (cells of `cell`, 8-neighbours), union-find over occupied cells.
std::vector<bool> large_patches(const PointCloudXYZ& points, const std::array<float, 4>& plane,
                                double cell, std::size_t min_points) {
  const double nx0 = plane[0], ny0 = plane[1], nz0 = plane[2];
  const double nn = std::sqrt(nx0 * nx0 + ny0 * ny0 + nz0 * nz0);
  const double n[3] = {nx0 / nn, ny0 / nn, nz0 / nn};
  const double helper[3] = {std::abs(n[0]) < 0.9 ? 1.0 : 0.0, std::abs(n[0]) < 0.9 ? 0.0 : 1.0, 0.0};
  auto cross = [](const double* a, const double* b, double* out) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
  };
  double u[3], v[3];
  cross(n, helper, u);
  const double un = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
  for (double& c : u) c /= un;
  cross(n, u, v);

  std::map<std::pair<std::int64_t, std::int64_t>, std::size_t> id;
  std::vector<std::size_t> cell_of(points.size());
  std::vector<std::size_t> count;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const double q[3] = {points[i].x, points[i].y, points[i].z};
    const double du = q[0] * u[0] + q[1] * u[1] + q[2] * u[2];
    const double dv = q[0] * v[0] + q[1] * v[1] + q[2] * v[2];
    const std::pair<std::int64_t, std::int64_t> key{static_cast<std::int64_t>(std::floor(du / cell)),
                                                    static_cast<std::int64_t>(std::floor(dv / cell))};
    auto it = id.emplace(key, id.size()).first;
    if (it->second == count.size()) count.push_back(0);
    ++count[it->second];
    cell_of[i] = it->second;
  }
  std::vector<std::size_t> parent(id.size());
  std::iota(parent.begin(), parent.end(), 0);
  auto root = [&parent](std::size_t i) {
    while (parent[i] != i) {
      parent[i] = parent[parent[i]];
      i = parent[i];
    }
    return i;
  };
  for (const auto& [key, k] : id) {
    const std::pair<std::int64_t, std::int64_t> steps[4] = {{1, -1}, {1, 0}, {1, 1}, {0, 1}};
    for (const auto& [da, db] : steps) {
      auto other = id.find({key.first + da, key.second + db});
      if (other == id.end()) continue;
      const std::size_t ra = root(k), rb = root(other->second);
      if (ra != rb) parent[std::max(ra, rb)] = std::min(ra, rb);
    }
  }
  std::vector<std::size_t> size(parent.size(), 0);
  for (std::size_t k = 0; k < count.size(); ++k) size[root(k)] += count[k];
  std::vector<bool> big(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) big[i] = size[root(cell_of[i])] >= min_points;
  return big;
}

// RANSAC plane fits (pcl::SACSegmentation's plane fit over PCL's own plane model, as the
// bridge's segment_plane_pcl: fit_plane_pcl): a plane is support
// only where its inliers form a connected patch of at least `min_patch` points; a plane's
// inliers are excluded from later fits either way. Remaining points keep their order.
PointCloudXYZ::Ptr remove_support(const PointCloudXYZ::Ptr& points, const ReferenceParams& p,
                                  std::size_t model_points, rust::Vec<ReferencePlane>& planes) {
  const auto min_patch = static_cast<std::size_t>(
      std::max(std::ceil(p.support_min_points_factor * static_cast<double>(model_points)), 3.0));
  const double tolerance = p.cluster_tolerance_factor * p.resolution;
  const float distance = static_cast<float>(p.support_distance);
  check_positive(distance, "plane distance threshold");
  if (p.support_ransac_iterations == 0) fail("plane fit needs at least one RANSAC iteration");
  std::vector<bool> removed(points->size(), false);
  std::vector<std::uint32_t> candidates(points->size());
  std::iota(candidates.begin(), candidates.end(), 0u);
  for (std::uint32_t round = 0; round < p.support_max_planes; ++round) {
    if (candidates.size() < min_patch) break;
    const auto cand = subset(*points, candidates);
    pcl::PointIndices inliers;
    std::vector<float> coefficients;
    fit_plane_pcl(cand, distance, p.support_ransac_iterations, inliers.indices, coefficients);
    if (inliers.indices.empty() || coefficients.size() != 4) break;
    if (inliers.indices.size() < min_patch) break;
    std::array<float, 4> plane{};
    for (std::size_t i = 0; i < 4; ++i) plane[i] = coefficients[i];
    const auto on_plane = subset(*cand, inliers.indices);
    const auto big = large_patches(*on_plane, plane, tolerance, min_patch);
    std::uint32_t taken = 0;
    for (std::size_t k = 0; k < big.size(); ++k) {
      if (big[k]) {
        removed[candidates[static_cast<std::size_t>(inliers.indices[k])]] = true;
        ++taken;
      }
    }
    if (taken > 0) {
      ReferencePlane rp{};
      for (std::size_t i = 0; i < 4; ++i) rp.coefficients[i] = plane[i];
      rp.points = taken;
      planes.push_back(rp);
    }
    std::vector<bool> is_inlier(candidates.size(), false);
    for (auto i : inliers.indices) is_inlier[static_cast<std::size_t>(i)] = true;
    std::vector<std::uint32_t> rest;
    rest.reserve(candidates.size() - inliers.indices.size());
    for (std::size_t k = 0; k < candidates.size(); ++k) {
      if (!is_inlier[k]) rest.push_back(candidates[k]);
    }
    candidates = std::move(rest);
  }
  PointCloudXYZ::Ptr out(new PointCloudXYZ);
  for (std::size_t i = 0; i < points->size(); ++i) {
    if (!removed[i]) out->push_back((*points)[i]);
  }
  finish(*out);
  return out;
}

// ---------------------------------------------------------------------------------------
// Model

// Keypoints and FPFH of the model for every radius (Algorithm 1 step 1a-b, model side).
struct ModelFeatures {
  KeypointSet set;
  std::vector<RadiusDescriptors> radii;
};

ModelFeatures model_features(const PointCloudXYZ::Ptr& model, const ReferenceParams& p) {
  ModelFeatures m;
  const auto idx = uniform_sampling_indices(model, static_cast<float>(p.initial_leaf));
  if (idx.size() < 3) {
    fail("model: ", idx.size(), " keypoints at the ", p.initial_leaf,
         " mm initial leaf; at least 3 are needed");
  }
  m.set = keypoint_set(model, idx, p.feature_surface_cloud);
  const std::array<double, 3> vp{p.model_viewpoint[0], p.model_viewpoint[1], p.model_viewpoint[2]};
  for (double r : p.fpfh_radii) {
    m.radii.push_back(fpfh(m.set.surface, m.set.surface_keypoints, r, p.normal_radius_factor, vp));
  }
  return m;
}

// ---------------------------------------------------------------------------------------
// One cluster (Algorithm 1 / 2 steps 1-5)

struct StageTimes {
  double model_features = 0, keypoints = 0, fpfh = 0, correspondences = 0, rejection = 0,
         svd = 0, euclidean = 0, icp = 0, outliers = 0, initial = 0, final_ = 0;
};

struct Initial {
  bool found = false;
  Pose pose = Pose::Identity();
  double score = 0.0;
  int radius_index = -1;
  double threshold = 0.0;
  std::size_t inliers = 0;
};

struct ClusterWork {
  std::uint32_t points = 0;
  ClusterOutcome outcome = ClusterOutcome::NoConsensus;
  double score = 0.0;
  bool detected = false;
  Initial initial;
  Pose pose = Pose::Identity();
  double final_score = 0.0, score_before_icp = 0.0;
  bool icp_converged = false, icp_adopted = false;
  std::uint32_t icp_iterations = 0;
  double icp_fitness = 0.0;
  IcpFailure icp_failure = IcpFailure::None;
  std::string icp_error;
  double icp_det = 0.0;
  StageTimes t;
  std::string error;
};

// ICP that also reports how many iterations it ran (a protected member in PCL).
class CountingIcp : public pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ, double> {
 public:
  int iterations() const { return nr_iterations_; }
};

// Steps A-C for one correspondence set and threshold: RANSAC rejection, SVD on the kept
// correspondences, Euclidean score against the cluster keypoints. False when no proper
// transform comes out.
bool hypothesis(const PointCloudXYZ::Ptr& model_kp, const PointCloudXYZ::Ptr& cluster_kp,
                const pcl::Correspondences& corrs, double threshold, const ReferenceParams& p,
                StageTimes& t, Pose& pose, double& score, std::size_t& inliers) {
  if (corrs.size() < 3) return false;
  auto t0 = Clock::now();
  pcl::registration::CorrespondenceRejectorSampleConsensus<pcl::PointXYZ> rej;
  rej.setInputSource(model_kp);
  rej.setInputTarget(cluster_kp);
  rej.setInlierThreshold(static_cast<float>(threshold));
  rej.setMaximumIterations(static_cast<int>(p.sac_iterations));
  rej.setRefineModel(false);
  rej.setSaveInliers(true);
  pcl::Correspondences kept;
  rej.getRemainingCorrespondences(corrs, kept);
  pcl::Indices inlier_idx;
  rej.getInliersIndices(inlier_idx);
  const Eigen::Matrix4f best = rej.getBestTransformation();
  t.rejection += ms_since(t0);
  if (inlier_idx.empty()) return false;  // no consensus
  const double det = static_cast<double>(best.topLeftCorner<3, 3>().determinant());
  if (std::abs(det - 1.0) > kDetTolerance) return false;  // reflection (PCL issue #1707)
  if (kept.size() < 3) return false;

  t0 = Clock::now();
  pcl::registration::TransformationEstimationSVD<pcl::PointXYZ, pcl::PointXYZ, double> svd;
  Pose m;
  svd.estimateRigidTransformation(*model_kp, *cluster_kp, kept, m);
  t.svd += ms_since(t0);
  if (!m.allFinite()) throw std::runtime_error("SVD produced a non-finite transform");
  if (!proper(m) || !rigid(m)) return false;

  t0 = Clock::now();
  score = euclidean_score(cluster_kp, *model_kp, m);
  t.euclidean += ms_since(t0);
  pose = m;
  inliers = kept.size();
  return true;
}

// Initial alignment of one cluster (Algorithm 1 or 2, step 1): the best hypothesis by
// Euclidean score, ties to the earlier (correspondence set, threshold) pair.
Initial initial_alignment(const PointCloudXYZ::Ptr& model, const PointCloudXYZ::Ptr& cluster,
                          const ReferenceParams& p, StageTimes& t) {
  Initial best;
  // (a) uniform keypoints on the world cluster and on the object (recomputed here, as the
  // thesis does for every cluster).
  auto t0 = Clock::now();
  const auto idx = uniform_sampling_indices(cluster, static_cast<float>(p.initial_leaf));
  t.keypoints += ms_since(t0);
  if (idx.size() < 3) return best;
  const KeypointSet cl = keypoint_set(cluster, idx, p.feature_surface_cloud);

  t0 = Clock::now();
  const auto m_idx = uniform_sampling_indices(model, static_cast<float>(p.initial_leaf));
  if (m_idx.size() < 3) fail("model: ", m_idx.size(), " keypoints at the initial leaf");
  const KeypointSet mk = keypoint_set(model, m_idx, p.feature_surface_cloud);
  t.model_features += ms_since(t0);

  const std::array<double, 3> scene_vp{p.scene_viewpoint[0], p.scene_viewpoint[1], p.scene_viewpoint[2]};
  const std::array<double, 3> model_vp{p.model_viewpoint[0], p.model_viewpoint[1], p.model_viewpoint[2]};
  const std::size_t n_th = p.sac_thresholds.size();
  const bool merged = p.algorithm == 2;

  // Sweeps the SAC thresholds over one correspondence set (step iii / 1d): one PCL rejector
  // per threshold on the correspondences as found.
  auto sweep = [&](const pcl::Correspondences& corrs, int radius_index) {
    for (std::size_t k = 0; k < n_th; ++k) {
      Pose pose;
      double score = 0.0;
      std::size_t inliers = 0;
      if (!hypothesis(mk.keypoints, cl.keypoints, corrs, p.sac_thresholds[k], p, t, pose, score,
                      inliers)) {
        continue;
      }
      if (!best.found || score < best.score) {  // strictly lower: earlier order wins ties
        best.found = true;
        best.pose = pose;
        best.score = score;
        best.radius_index = radius_index;
        best.threshold = p.sac_thresholds[k];
        best.inliers = inliers;
      }
    }
  };

  // (b) for each FPFH radius: features on object and cluster, correspondences, then either
  // the threshold sweep (Algorithm 1) or accumulation for the merged set (Algorithm 2).
  std::vector<pcl::Correspondences> sets;
  for (std::size_t r = 0; r < p.fpfh_radii.size(); ++r) {
    const double radius = p.fpfh_radii[r];
    t0 = Clock::now();
    const auto m = fpfh(mk.surface, mk.surface_keypoints, radius, p.normal_radius_factor, model_vp);
    t.model_features += ms_since(t0);
    t0 = Clock::now();
    const auto c = fpfh(cl.surface, cl.surface_keypoints, radius, p.normal_radius_factor, scene_vp);
    t.fpfh += ms_since(t0);
    if (c.descriptors->empty()) continue;
    t0 = Clock::now();
    auto corrs = match(m, c);
    t.correspondences += ms_since(t0);
    if (merged) {
      sets.push_back(std::move(corrs));
    } else {
      sweep(corrs, static_cast<int>(r));
    }
  }
  if (merged) {
    t0 = Clock::now();
    const auto all = merge_best(sets, mk.keypoints->size());
    t.correspondences += ms_since(t0);
    sweep(all, -1);
  }
  return best;
}

// Final alignment (step 3): ICP of the model's final keypoints onto the world's, percent of
// outliers before and after, the ICP pose adopted only if it scores better.
void final_alignment(const PointCloudXYZ::Ptr& model_final, const PointCloudXYZ::Ptr& world_final,
                     const ReferenceParams& p, ClusterWork& w) {
  const Pose initial = w.initial.pose;
  const double d = p.outlier_distance;
  auto t0 = Clock::now();
  const double before = outlier_percent(world_final, *model_final, initial, d);
  w.t.outliers += ms_since(t0);

  t0 = Clock::now();
  bool have_refined = false;
  Pose refined = Pose::Identity();
  try {
    CountingIcp icp;
    icp.setInputSource(model_final);
    icp.setInputTarget(world_final);
    icp.setMaxCorrespondenceDistance(p.icp_max_correspondence);
    icp.setMaximumIterations(static_cast<int>(p.icp_iterations));
    icp.setTransformationEpsilon(p.icp_transformation_epsilon);
    PointCloudXYZ aligned;
    icp.align(aligned, initial);
    const Pose out = icp.getFinalTransformation();
    if (!proper(out)) {
      w.icp_failure = IcpFailure::ImproperRotation;
      w.icp_det = rotation_det(out);
    } else {
      w.icp_converged = icp.hasConverged();
      w.icp_iterations = static_cast<std::uint32_t>(std::max(icp.iterations(), 0));
      w.icp_fitness = icp.getFitnessScore(p.icp_max_correspondence);
      if (rigid(out)) {
        refined = out;
        have_refined = true;
      }
    }
  } catch (const std::exception& e) {
    w.icp_failure = IcpFailure::Pcl;
    w.icp_error = e.what();
  }
  w.t.icp += ms_since(t0);

  w.pose = initial;
  w.final_score = before;
  w.score_before_icp = before;
  if (have_refined) {
    t0 = Clock::now();
    const double after = outlier_percent(world_final, *model_final, refined, d);
    // "If the score is better than before" (3d); equal percentages are decided by the
    // Euclidean score of the same keypoints, which ICP minimises.
    const bool better =
        after < before ||
        (after == before && euclidean_score(world_final, *model_final, refined) <
                                euclidean_score(world_final, *model_final, initial));
    w.t.outliers += ms_since(t0);
    if (better) {
      w.icp_adopted = true;
      w.pose = refined;
      w.final_score = after;
    }
  }
}

void search_cluster(const PointCloudXYZ::Ptr& world, const std::vector<std::uint32_t>& idx,
                    const PointCloudXYZ::Ptr& model, const PointCloudXYZ::Ptr& model_final,
                    const PointCloudXYZ::Ptr& world_final, const ReferenceParams& p,
                    ClusterWork& w) {
  w.points = static_cast<std::uint32_t>(idx.size());
  const auto cluster = subset(*world, idx);
  auto t0 = Clock::now();
  w.initial = initial_alignment(model, cluster, p, w.t);
  w.t.initial += ms_since(t0);
  if (!w.initial.found) {
    w.outcome = ClusterOutcome::NoConsensus;
    return;
  }
  // Step 2: keep only initial transformations with a good score.
  if (w.initial.score >= p.initial_score_max) {
    w.outcome = ClusterOutcome::InitialRejected;
    w.score = w.initial.score;
    return;
  }
  t0 = Clock::now();
  final_alignment(model_final, world_final, p, w);
  w.t.final_ += ms_since(t0);
  // Step 4: keep only final transformations with a good score.
  if (w.final_score >= p.final_score_max) {
    w.outcome = ClusterOutcome::FinalRejected;
    w.score = w.final_score;
    return;
  }
  w.outcome = ClusterOutcome::Accepted;
  w.detected = true;
}

void check_params(const ReferenceParams& p) {
  if (p.algorithm != 1 && p.algorithm != 2) fail("algorithm must be 1 or 2, got ", int(p.algorithm));
  check_positive(p.resolution, "resolution");
  check_positive(p.cluster_tolerance_factor, "cluster tolerance factor");
  check_positive(p.cluster_min_factor, "cluster min factor");
  check_positive(p.cluster_max_factor, "cluster max factor");
  check_positive(p.initial_leaf, "initial leaf");
  check_positive(p.final_leaf, "final leaf");
  check_positive(p.normal_radius_factor, "normal radius factor");
  check_positive(p.initial_score_max, "initial score threshold");
  check_positive(p.final_score_max, "final score threshold");
  check_positive(p.outlier_distance, "outlier distance");
  check_positive(p.icp_max_correspondence, "ICP max correspondence distance");
  check_positive(p.icp_transformation_epsilon, "ICP transformation epsilon");
  if (p.icp_iterations == 0) fail("ICP needs at least one iteration");
  if (p.sac_iterations == 0) fail("SAC rejector needs at least one iteration");
  if (p.fpfh_radii.empty()) fail("no FPFH radii");
  for (double r : p.fpfh_radii) check_positive(r, "FPFH radius");
  if (p.sac_thresholds.empty()) fail("no SAC thresholds");
  for (double t : p.sac_thresholds) check_positive(t, "SAC inlier threshold");
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(p.scene_viewpoint[i]) || !std::isfinite(p.model_viewpoint[i])) {
      fail("viewpoint must be 3 finite coordinates");
    }
    if (p.roi_enabled && !(std::isfinite(p.roi_min[i]) && std::isfinite(p.roi_max[i]) &&
                           p.roi_min[i] < p.roi_max[i])) {
      fail("region of interest needs finite bounds with min < max on every axis");
    }
  }
}

}  // namespace

ReferenceResult reference_recognize(rust::Slice<const float> model_xyz,
                                    rust::Slice<const float> scene_xyz,
                                    const ReferenceParams& p) {
  const auto start = Clock::now();
  check_params(p);
  ReferenceResult out{};
  out.timings = ReferenceTimings{};
  out.timings.omp_max_active_levels = omp_get_max_active_levels();

  // --- Model (checked up front; its keypoints and FPFH are recomputed per cluster) ------
  auto t0 = Clock::now();
  const auto model_in = from_xyz(model_xyz, "model");
  const auto model = voxel_grid(model_in, static_cast<float>(p.resolution), "model voxel grid");
  if (model->size() < kMinModelPoints) {
    fail("model: only ", model->size(), " points remain after the ", p.resolution,
         " mm voxel grid (need ", kMinModelPoints,
         "); is the resolution too coarse or the cloud in the wrong units?");
  }
  {
    const auto check = model_features(model, p);
    for (std::size_t r = 0; r < check.radii.size(); ++r) {
      if (check.radii[r].descriptors->size() < 3) {
        fail("model: only ", check.radii[r].descriptors->size(),
             " keypoints have an FPFH descriptor at radius ", p.fpfh_radii[r], " mm");
      }
    }
  }
  const auto model_final = subset(*model, uniform_sampling_indices(model, static_cast<float>(p.final_leaf)));
  for (const auto& q : model_final->points) {
    out.model_final_keypoints.push_back(q.x);
    out.model_final_keypoints.push_back(q.y);
    out.model_final_keypoints.push_back(q.z);
  }
  out.timings.model_preparation_ms = ms_since(t0);

  // --- Scene: region of interest, voxel grid, supporting surface -------------------------
  t0 = Clock::now();
  const auto scene = from_xyz(scene_xyz, "scene");
  out.input_points = scene->size();
  PointCloudXYZ::Ptr cropped = scene;
  if (p.roi_enabled) {
    cropped.reset(new PointCloudXYZ);
    for (const auto& q : scene->points) {
      const double c[3] = {q.x, q.y, q.z};
      bool inside = true;
      for (int k = 0; k < 3; ++k) inside = inside && c[k] >= p.roi_min[k] && c[k] <= p.roi_max[k];
      if (inside) cropped->push_back(q);
    }
    finish(*cropped);
  }
  out.outside_roi = scene->size() - cropped->size();
  if (cropped->empty()) fail("scene: no point lies inside the region of interest");
  auto world = voxel_grid(cropped, static_cast<float>(p.resolution), "scene voxel grid");
  out.voxel_merged = cropped->size() - world->size();
  if (p.support_enabled) world = remove_support(world, p, model->size(), out.support_planes);
  out.remaining = world->size();
  out.timings.preprocess_ms = ms_since(t0);
  if (world->size() < 3) {
    out.timings.total_ms = ms_since(start);
    return out;
  }

  // --- Euclidean clusters (3.4.1.3) and the world's final keypoints (step 3a) -----------
  t0 = Clock::now();
  const double n_model = static_cast<double>(model->size());
  const double min_size = std::max(std::ceil(p.cluster_min_factor * n_model), 1.0);
  const double max_size = std::max(std::floor(p.cluster_max_factor * n_model), min_size);
  std::vector<pcl::PointIndices> found;
  {
    pcl::EuclideanClusterExtraction<pcl::PointXYZ> ec;
    ec.setClusterTolerance(static_cast<float>(p.cluster_tolerance_factor * p.resolution));
    ec.setMinClusterSize(static_cast<pcl::uindex_t>(min_size));
    ec.setMaxClusterSize(static_cast<pcl::uindex_t>(
        std::min(max_size, static_cast<double>(std::numeric_limits<std::uint32_t>::max()))));
    ec.setInputCloud(world);
    ec.extract(found);
  }
  for (auto& f : found) std::sort(f.indices.begin(), f.indices.end());
  std::sort(found.begin(), found.end(), [](const pcl::PointIndices& a, const pcl::PointIndices& b) {
    return a.indices.front() < b.indices.front();
  });
  std::vector<std::vector<std::uint32_t>> clusters;
  for (const auto& f : found) {
    clusters.emplace_back();
    for (auto i : f.indices) clusters.back().push_back(static_cast<std::uint32_t>(i));
  }
  const auto world_final = subset(*world, uniform_sampling_indices(world, static_cast<float>(p.final_leaf)));
  out.timings.clustering_ms = ms_since(t0);

  // --- For each cluster, in parallel (4.4): initial then final alignment ---------------
  const int n = static_cast<int>(clusters.size());
  std::vector<ClusterWork> work(clusters.size());
  const int team = p.threads > 0 ? static_cast<int>(p.threads) : omp_get_max_threads();
  int used = 1;
#pragma omp parallel for num_threads(team)
  for (int i = 0; i < n; ++i) {
    if (omp_get_thread_num() == 0) used = omp_get_num_threads();
    auto& w = work[static_cast<std::size_t>(i)];
    try {
      search_cluster(world, clusters[static_cast<std::size_t>(i)], model, model_final, world_final, p, w);
    } catch (const std::exception& e) {
      w.error = e.what();
      if (w.error.empty()) w.error = "unknown error";
    } catch (...) {
      w.error = "unknown error";
    }
  }
  out.timings.omp_threads = static_cast<std::uint32_t>(used);

  for (std::size_t i = 0; i < work.size(); ++i) {
    if (!work[i].error.empty()) {
      throw std::runtime_error("cluster " + std::to_string(i) + ": " + work[i].error);
    }
  }
  auto& T = out.timings;
  for (std::size_t i = 0; i < work.size(); ++i) {
    const auto& w = work[i];
    T.initial_alignment_ms += w.t.initial;
    T.final_alignment_ms += w.t.final_;
    T.model_features_ms += w.t.model_features;
    T.cluster_keypoints_ms += w.t.keypoints;
    T.cluster_fpfh_ms += w.t.fpfh;
    T.correspondences_ms += w.t.correspondences;
    T.rejection_ms += w.t.rejection;
    T.svd_ms += w.t.svd;
    T.euclidean_score_ms += w.t.euclidean;
    T.icp_ms += w.t.icp;
    T.outlier_score_ms += w.t.outliers;
    ReferenceCluster c{};
    c.points = w.points;
    c.outcome = w.outcome;
    c.score = w.score;
    out.clusters.push_back(c);
    if (!w.detected) continue;
    ReferenceDetection d{};
    d.pose = row_major(w.pose);
    d.initial_pose = row_major(w.initial.pose);
    d.initial_score = w.initial.score;
    d.final_score = w.final_score;
    d.score_before_icp = w.score_before_icp;
    d.cluster = static_cast<std::uint32_t>(i);
    d.fpfh_radius_index = w.initial.radius_index;
    d.sac_threshold = w.initial.threshold;
    d.sac_inliers = static_cast<std::uint32_t>(w.initial.inliers);
    d.icp_converged = w.icp_converged;
    d.icp_iterations = w.icp_iterations;
    d.icp_fitness = w.icp_fitness;
    d.icp_adopted = w.icp_adopted;
    d.icp_failure = w.icp_failure;
    d.icp_error = rust::String(w.icp_error);
    d.icp_det = w.icp_det;
    out.detections.push_back(std::move(d));
  }
  T.total_ms = ms_since(start);
  return out;
}

}  // namespace binpick
