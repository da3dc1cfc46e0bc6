// pcl::SACSegmentation::segment (plane, RANSAC, optimised coefficients, 1.0 mm, 300
// iterations) from Debian's precompiled libpcl_segmentation, on a cloud of little-endian f32
// x y z triples: prints the coefficients' bits, the inlier count and an FNV-1a hash of the
// inlier indices. The bridge test `plane_fit_is_the_same_on_any_number_of_threads` holds the
// bridge's plane fit to these figures; `BINPICK_GOLDEN_DIR=/tmp cargo test --release -p
// binpick-pcl --test bridge plane_fit_is_the_same` writes its two clouds there. Build and run:
//   g++ -O2 -std=c++17 scripts/golden/sac_segmentation.cpp -o /tmp/sac_segmentation \
//     -I/usr/include/pcl-1.13 -I/usr/include/eigen3 \
//     -lpcl_segmentation -lpcl_sample_consensus -lpcl_common
//   /tmp/sac_segmentation /tmp/plane-90000.bin; /tmp/sac_segmentation /tmp/plane-6000.bin
#include <pcl/segmentation/sac_segmentation.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <vector>

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s points.bin (f32 x y z triples)\n", argv[0]);
    return 2;
  }
  std::ifstream file(argv[1], std::ios::binary);
  if (!file) {
    std::fprintf(stderr, "cannot read %s\n", argv[1]);
    return 1;
  }
  const std::vector<char> raw((std::istreambuf_iterator<char>(file)), {});
  if (raw.size() % 12 != 0) {
    std::fprintf(stderr, "%s: %zu bytes, not whole f32 triples\n", argv[1], raw.size());
    return 1;
  }
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  for (std::size_t at = 0; at < raw.size(); at += 12) {
    float xyz[3];
    std::memcpy(xyz, raw.data() + at, 12);
    cloud->push_back(pcl::PointXYZ(xyz[0], xyz[1], xyz[2]));
  }
  pcl::SACSegmentation<pcl::PointXYZ> seg;
  seg.setOptimizeCoefficients(true);
  seg.setModelType(pcl::SACMODEL_PLANE);
  seg.setMethodType(pcl::SAC_RANSAC);
  seg.setDistanceThreshold(1.0);
  seg.setMaxIterations(300);
  seg.setInputCloud(cloud);
  pcl::PointIndices inliers;
  pcl::ModelCoefficients coefficients;
  seg.segment(inliers, coefficients);
  if (coefficients.values.size() != 4) {
    std::printf("no plane\n");
    return 1;
  }
  std::uint64_t hash = 0xcbf29ce484222325ull;
  for (int i : inliers.indices) hash = (hash ^ static_cast<std::uint32_t>(i)) * 0x100000001b3ull;
  std::uint32_t bits[4];
  std::memcpy(bits, coefficients.values.data(), sizeof bits);
  std::printf("%zu points: coefficients [%u, %u, %u, %u], %zu inliers, hash %016llx\n",
              cloud->size(), bits[0], bits[1], bits[2], bits[3], inliers.indices.size(),
              static_cast<unsigned long long>(hash));
  return 0;
}
