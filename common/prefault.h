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

#endif
