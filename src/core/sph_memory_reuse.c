/* Keep freed memory in the process (sph_memory.f90, keep_freed_memory). glibc's malloc
 * serves every block above its mmap threshold (128 KiB, raised up to 32 MiB as such blocks
 * are freed) with fresh pages from the kernel and hands them back on free, so each remesh and
 * each rebuild of a scratch array pays a page fault per 4 KiB page on first touch again
 * (measured: 0.42 million faults and 1.2 s of system time in sphremesh_bench_remesh). With
 * the threshold at its maximum and no trimming, freed blocks stay mapped and the next
 * allocation reuses them; blocks above 32 MiB are still mapped afresh. The peak resident set
 * does not change (what is kept is reused, not added to). A no-op outside glibc. */
#if defined(__GLIBC__) || defined(__linux__)
#include <malloc.h>
#endif

void sph_keep_freed_memory(void)
{
#if defined(M_MMAP_THRESHOLD) && defined(M_TRIM_THRESHOLD)
    /* 32 MiB: glibc's largest mmap threshold on 64-bit systems (DEFAULT_MMAP_THRESHOLD_MAX) */
    (void)mallopt(M_MMAP_THRESHOLD, 32 * 1024 * 1024);
    /* trim only above 1 GiB of free memory at the heap's top */
    (void)mallopt(M_TRIM_THRESHOLD, 1024 * 1024 * 1024);
#endif
}
