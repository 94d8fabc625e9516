#include "apps/sweep_mpi.hpp"

#include <cstdlib>

#ifdef UKDYN_HAVE_MPI
#include <mpi.h>

#include <numeric>
#include <stdexcept>
#include <string>
#include <vector>
#endif

namespace ukdyn_app {

namespace {
bool under_mpirun() {
  return std::getenv("OMPI_COMM_WORLD_SIZE") != nullptr || std::getenv("PMIX_RANK") != nullptr ||
         std::getenv("PMI_SIZE") != nullptr;
}
}  // namespace

#ifdef UKDYN_HAVE_MPI

bool mpi_built() { return true; }

namespace {

class MpiComm final : public ukdyn::SweepComm {
 public:
  MpiComm(int* argc, char*** argv) {
    MPI_Init(argc, argv);
    MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
    MPI_Comm_size(MPI_COMM_WORLD, &size_);
  }
  ~MpiComm() override { MPI_Finalize(); }
  MpiComm(const MpiComm&) = delete;
  MpiComm& operator=(const MpiComm&) = delete;
  [[nodiscard]] int rank() const override { return rank_; }
  [[nodiscard]] int size() const override { return size_; }

  // Sizes first (MPI_Gather), then the bytes (MPI_Gatherv), both to rank 0.
  std::vector<std::string> gather(const std::string& mine) override {
    if (mine.size() > static_cast<std::size_t>(1) << 30)
      throw std::runtime_error("MPI gather: more than 1 GiB of rows on one rank");
    const int n = static_cast<int>(mine.size());
    std::vector<int> sizes(static_cast<std::size_t>(size_), 0);
    MPI_Gather(&n, 1, MPI_INT, sizes.data(), 1, MPI_INT, 0, MPI_COMM_WORLD);
    std::vector<int> displs(static_cast<std::size_t>(size_), 0);
    long total = 0;
    for (int r = 0; r < size_; ++r) {
      displs[static_cast<std::size_t>(r)] = static_cast<int>(total);
      total += sizes[static_cast<std::size_t>(r)];
    }
    std::string all(rank_ == 0 ? static_cast<std::size_t>(total) : 0, '\0');
    MPI_Gatherv(mine.data(), n, MPI_CHAR, all.data(), sizes.data(), displs.data(), MPI_CHAR, 0,
                MPI_COMM_WORLD);
    std::vector<std::string> out;
    if (rank_ != 0) return out;
    for (int r = 0; r < size_; ++r) {
      out.push_back(all.substr(static_cast<std::size_t>(displs[static_cast<std::size_t>(r)]),
                               static_cast<std::size_t>(sizes[static_cast<std::size_t>(r)])));
    }
    return out;
  }

 private:
  int rank_ = 0, size_ = 1;
};

}  // namespace

std::unique_ptr<ukdyn::SweepComm> make_mpi_comm(int* argc, char*** argv) {
  if (!under_mpirun()) return nullptr;
  return std::make_unique<MpiComm>(argc, argv);
}

#else

bool mpi_built() { return false; }

std::unique_ptr<ukdyn::SweepComm> make_mpi_comm(int* /*argc*/, char*** /*argv*/) {
  static_cast<void>(under_mpirun);
  return nullptr;
}

#endif

}  // namespace ukdyn_app
