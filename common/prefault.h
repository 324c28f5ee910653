/* prefault — the pages of a range of memory mapped for writing at once:
 * one system call where each page's first store would take a fault (some
 * 5-15 us each on this project's virtual machines, the kernel's work and
 * the hypervisor's).  For memory a process is about to write whole: fresh
 * pages of the engine's shared segment that it copies into, its share of a
 * bump allocator there. */
#ifndef VOXD_PREFAULT_H
#define VOXD_PREFAULT_H

#include <stddef.h>

/* The pages of [p, p + n) made present and writable in this process
 * (MADV_POPULATE_WRITE, Linux 5.14; their bytes unchanged); an
 * optimization only: where the kernel cannot, nothing happens and the
 * stores fault as before. */
void prefault_write(void *p, size_t n);

/* n bytes from src to fresh memory at to, its pages made present first
 * (prefault_write) rather than one fault each as the copy goes. */
void prefault_copy(void *to, const void *src, size_t n);

/* Copies into fresh memory made by `threads` threads at once (par_run),
 * thread k making the k-th part of each: the copies' time is the first
 * touch of their pages, which one thread alone makes a serial span of a
 * job's start (the dragon's 17 MB of vertices, triangles and bins: 15 ms). */
typedef struct {
    void *to;
    const void *from;
    size_t bytes;
} prefault_span;
void prefault_copy_par(const prefault_span *spans, int count, unsigned threads);

#endif
