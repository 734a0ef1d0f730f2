// pcl_normals: PCL's normal estimators on one cloud, timed by themselves, for `triplet-normal bench`.
// evaluation/pcl.py compiles it on first use (g++ with pkg-config's flags for PCL) and runs it once per cloud.
//
// Usage: pcl_normals POINTS HEIGHT WIDTH REPEATS THREADS OUT_DIR
//   POINTS   HEIGHT * WIDTH * 3 float32 in the machine's byte order: x, y, z of each point, row by row; a point
//            without a return is NaN.
//   HEIGHT   rows of the organized frame; 1 for an unorganized cloud, where the integral images cannot run.
//   WIDTH    points per row.
//   REPEATS  timed runs of each estimator after one warm-up run.
//   THREADS  NormalEstimationOMP's threads.
//   OUT_DIR  where each estimator writes METHOD.f32: HEIGHT * WIDTH * 3 float32 normals, NaN where PCL gives none.
//
// Prints one JSON line: {"pcl": "1.13.0", "seconds": {"METHOD": [run, ...], ...}}. A run's seconds are std::chrono
// around handing the cloud to the estimator and compute(): the integral images are built when the cloud is handed
// over (setInputCloud), the KD-tree inside compute(), so both belong to the estimate; reading and writing files and
// the process's start do not.
//
// Methods:
//   average_3d_gradient, covariance_matrix  IntegralImageNormalEstimation (organized clouds only) with the settings
//       of PCL's integral-image tutorial: MaxDepthChangeFactor 0.02, NormalSmoothingSize 10 (pixels).
//   omp_knn30  NormalEstimationOMP over the 30 nearest points (setKSearch(30)) from a KD-tree, as PCL's normal
//       estimation tutorial searches; no radius, since PCL takes either a radius or k, not both.

#include <pcl/features/integral_image_normal.h>
#include <pcl/features/normal_3d_omp.h>
#include <pcl/pcl_config.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZ>;
using Normals = pcl::PointCloud<pcl::Normal>;
using Integral = pcl::IntegralImageNormalEstimation<pcl::PointXYZ, pcl::Normal>;

constexpr float kMaxDepthChangeFactor = 0.02f;
constexpr float kNormalSmoothingSize = 10.0f;
constexpr int kNeighbours = 30;

Cloud::Ptr read_cloud(const std::string& path, std::uint32_t height, std::uint32_t width) {
  auto cloud = std::make_shared<Cloud>(width, height);
  std::vector<float> xyz(cloud->size() * 3);
  std::ifstream in(path, std::ios::binary);
  const auto bytes = static_cast<std::streamsize>(xyz.size() * sizeof(float));
  if (!in.read(reinterpret_cast<char*>(xyz.data()), bytes)) {
    throw std::runtime_error(path + ": fewer than HEIGHT * WIDTH * 3 float32");
  }
  for (std::size_t i = 0; i < cloud->size(); ++i) {
    (*cloud)[i].x = xyz[3 * i];
    (*cloud)[i].y = xyz[3 * i + 1];
    (*cloud)[i].z = xyz[3 * i + 2];
  }
  cloud->is_dense = false;  // NaN points: PCL's estimators and KD-tree skip them only when told
  return cloud;
}

void write_normals(const std::string& path, const Normals& normals) {
  std::vector<float> xyz;
  xyz.reserve(normals.size() * 3);
  for (const auto& n : normals) {
    xyz.insert(xyz.end(), {n.normal_x, n.normal_y, n.normal_z});
  }
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(xyz.data()), static_cast<std::streamsize>(xyz.size() * sizeof(float)));
  if (!out) {
    throw std::runtime_error(path + ": cannot write");
  }
}

// One warm-up run, then `repeats` timed runs of `estimate`, which hands the cloud over and computes into `normals`.
std::vector<double> timed(const std::function<void(Normals&)>& estimate, Normals& normals, int repeats) {
  estimate(normals);
  std::vector<double> seconds;
  for (int i = 0; i < repeats; ++i) {
    const auto start = std::chrono::steady_clock::now();
    estimate(normals);
    seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  return seconds;
}

std::function<void(Normals&)> integral_image(const Cloud::ConstPtr& cloud, Integral::NormalEstimationMethod method) {
  auto estimator = std::make_shared<Integral>();
  estimator->setNormalEstimationMethod(method);
  estimator->setMaxDepthChangeFactor(kMaxDepthChangeFactor);
  estimator->setNormalSmoothingSize(kNormalSmoothingSize);
  return [estimator, cloud](Normals& normals) {
    estimator->setInputCloud(cloud);
    estimator->compute(normals);
  };
}

std::function<void(Normals&)> omp_knn(const Cloud::ConstPtr& cloud, int threads) {
  auto estimator = std::make_shared<pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal>>(threads);
  estimator->setSearchMethod(std::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
  estimator->setKSearch(kNeighbours);
  return [estimator, cloud](Normals& normals) {
    estimator->setInputCloud(cloud);
    estimator->compute(normals);
  };
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 7) {
    std::cerr << "usage: pcl_normals POINTS HEIGHT WIDTH REPEATS THREADS OUT_DIR\n";
    return 2;
  }
  try {
    const auto height = static_cast<std::uint32_t>(std::stoul(argv[2]));
    const auto width = static_cast<std::uint32_t>(std::stoul(argv[3]));
    const int repeats = std::stoi(argv[4]);
    const int threads = std::stoi(argv[5]);
    const std::string out_dir = argv[6];
    const Cloud::ConstPtr cloud = read_cloud(argv[1], height, width);

    std::vector<std::pair<std::string, std::function<void(Normals&)>>> methods;
    if (cloud->isOrganized()) {
      methods.emplace_back("average_3d_gradient", integral_image(cloud, Integral::AVERAGE_3D_GRADIENT));
      methods.emplace_back("covariance_matrix", integral_image(cloud, Integral::COVARIANCE_MATRIX));
    }
    methods.emplace_back("omp_knn" + std::to_string(kNeighbours), omp_knn(cloud, threads));

    std::ostringstream json;
    json.precision(9);
    json << "{\"pcl\": \"" << PCL_VERSION_PRETTY << "\", \"seconds\": {";
    for (std::size_t m = 0; m < methods.size(); ++m) {
      Normals normals;
      const auto seconds = timed(methods[m].second, normals, repeats);
      write_normals(out_dir + "/" + methods[m].first + ".f32", normals);
      json << (m ? ", " : "") << "\"" << methods[m].first << "\": [";
      for (std::size_t i = 0; i < seconds.size(); ++i) {
        json << (i ? ", " : "") << seconds[i];
      }
      json << "]";
    }
    json << "}}";
    std::cout << json.str() << std::endl;
  } catch (const std::exception& error) {
    std::cerr << "pcl_normals: " << error.what() << "\n";
    return 1;
  }
  return 0;
}
