// The MPI backend of `ukdyn sweep` (Debian's OpenMPI; built when CMake finds MPI): a SweepComm
// over MPI_COMM_WORLD. Only the ukdyn executable links MPI; the library stays free of it.
#pragma once

#include <memory>

#include "ukdyn/sweep/sweep.hpp"

namespace ukdyn_app {

/// True if this ukdyn was built with MPI.
bool mpi_built();

/// Under mpirun (OMPI_COMM_WORLD_SIZE, PMIX_RANK or PMI_SIZE in the environment): initialises MPI
/// and returns a communicator (finalised when destroyed). Otherwise nullptr (no MPI_Init).
std::unique_ptr<ukdyn::SweepComm> make_mpi_comm(int* argc, char*** argv);

}  // namespace ukdyn_app
