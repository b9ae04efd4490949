/* Keep freed memory in the process (sph_memory.f90, keep_freed_memory). glibc's malloc
 * serves every block above its mmap threshold (128 KiB, raised up to 32 MiB as such blocks
 * are freed) with fresh pages from the kernel and hands them back on free, so each remesh and
 * each rebuild of a scratch array pays a page fault per 4 KiB page on first touch again
 * (measured: 0.42 million faults and 1.2 s of system time in sphremesh_bench_remesh). With
 * every block on the heap and no trimming, freed blocks stay mapped and the next allocation
 * reuses them. A no-op outside glibc. */
#if defined(__GLIBC__) || defined(__linux__)
#include <malloc.h>
#endif

void sph_keep_freed_memory(void)
{
#if defined(M_MMAP_MAX) && defined(M_TRIM_THRESHOLD)
    /* no block is mapped on its own: remeshing's transfer sums (128 bytes per new particle
     * in 2D, 57 MB for a refinement of 10^5 particles) were above the largest threshold
     * glibc accepts (32 MiB) and cost 35 ms of faults, an eighth of the pass, every time */
    (void)mallopt(M_MMAP_MAX, 0);
    /* trim only above 1 GiB of free memory at the heap's top */
    (void)mallopt(M_TRIM_THRESHOLD, 1024 * 1024 * 1024);
#endif
}
