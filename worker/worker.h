/* worker — the worker process loop (Figure 3's slave).
 *
 * A worker is forked by the engine before any job and lives across jobs.
 * It waits on its slot's futex until the master hands it a task (task_seq
 * moves), runs it, publishes the results in its 8-entry queue, marks the
 * task done (done_seq) and rings the master's doorbell.  The task's kind
 * picks the kernel (work.h, shm/kinds.h); a worker reads the job's block
 * and writes only its own slot, its queue and what its kind's block lets
 * it.  See shm/shm.h for the layout and the sleeping protocol.
 */
#ifndef VOXD_WORKER_H
#define VOXD_WORKER_H

#include <stdint.h>

/* The child's side of fork(): sets PR_SET_PDEATHSIG (SIGKILL), checks the
 * master is still its parent, resets the signals, closes every inherited
 * descriptor but 0-2, then serves slot `index` of the segment at base until
 * told to exit.  Never returns (_exit). */
_Noreturn void worker_main(uint8_t *base, uint32_t index);

#endif
