/* heap — a process's freed memory kept while it works and given back when
 * it waits (glibc's malloc; elsewhere both do nothing).
 *
 * glibc hands a large block back to the kernel at its free (mmap'd, or the
 * heap's top trimmed), and the next allocation of the same size takes a
 * page fault for each of its pages again; a fault costs microseconds on a
 * virtual machine.  A process that allocates and frees the same large
 * arrays task after task (a worker, the daemon's engine thread) keeps
 * them (heap_keep) and gives what it holds back when it has nothing to do
 * (heap_give_back), so that an idle daemon holds no more than it needs. */
#ifndef VOXD_HEAP_H
#define VOXD_HEAP_H

/* Blocks up to 32 MiB from the heap, freed ones kept up to 1 GiB, and one
 * arena for every thread (so that heap_give_back reaches what any of them
 * freed: glibc trims the free top of the main arena alone, and a thread's
 * own arena only at a free of its own): for the whole process (mallopt),
 * at its start, before a second thread. */
void heap_keep(void);
/* What the heap holds free given back to the kernel: every arena's free
 * blocks and the main arena's free top (all of it, after heap_keep). */
void heap_give_back(void);

#endif
