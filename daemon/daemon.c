/* The daemon's loop: the listening socket, signals (uv_signal_t: the
 * handlers only queue them, the loop acts), the housekeeping timer, the
 * configuration reload and the way out. */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
#include "daemon.h"
#include "log.h"
#include "proto_check.h"

int daemon_load_config(const daemon_options *o, voxd_config *c, err_info *err)
{
    const char *path = o->config_path;
    if (!path && access(CONFIG_DEFAULT_PATH, F_OK) == 0) path = CONFIG_DEFAULT_PATH;
    int rc = 0;
    if (path) rc = config_load(path, c, err);
    else config_defaults(c);
    if (rc) return rc;
    if (o->socket) snprintf(c->socket, sizeof c->socket, "%s", o->socket);
    if (o->workers) c->workers = o->workers;
    if (o->client_timeout) c->client_timeout = o->client_timeout;
    if (o->stall_timeout >= 0) c->worker_stall_timeout = (uint32_t)o->stall_timeout;
    return 0;
}

void daemon_engine_opts(daemon_ctx *d, const voxd_config *c)
{
    memcpy(d->cpus, c->cpus, sizeof d->cpus);
    d->mem_max = config_max_memory(c);
    /* the default fits /dev/shm (a container's 64 MiB runs small jobs);
     * a size the file gives is taken as it is, or refused by the engine */
    uint64_t fit = engine_shm_default(config_workers(c));
    d->mem_shm = c->shm_size_set || fit > c->shm_size ? c->shm_size : fit;
    daemon_mpi *m = &d->mpi;
    snprintf(m->hostfile, sizeof m->hostfile, "%s", c->mpi_hostfile);
    snprintf(m->mpirun, sizeof m->mpirun, "%s", c->mpirun);
    snprintf(m->args, sizeof m->args, "%s", c->mpirun_args);
    snprintf(m->vox_mpi, sizeof m->vox_mpi, "%s", c->vox_mpi);
    m->min_res = c->mpi_min_res;
    m->ranks = c->mpi_ranks;
    m->workers = c->mpi_workers;
    d->eopts = (engine_opts){.workers = config_workers(c),
                             .cpus = c->n_cpus ? d->cpus : NULL,
                             .ncpus = c->n_cpus,
                             .shm_bytes = (size_t)d->mem_shm,
                             .shm_option = "voxd.conf's shm_size",
                             .shm_name = d->shm_name,
                             /* 0 in the file: never (-1 to the engine) */
                             .stall_timeout = c->worker_stall_timeout
                                                  ? (double)c->worker_stall_timeout
                                                  : -1.0};
}

/* ---------------------------------------------------------------- the socket */

/* Created under umask 0177 (owner only), then given its group and mode:
 * never, not for an instant, more open than the config says. */
static int listen_on(daemon_ctx *d)
{
    const voxd_config *c = &d->cfg;
    int rc = uv_pipe_init(d->loop, &d->listener, 0);
    if (rc) return rc;
    d->listener.data = d;
    d->listening = 1;
    mode_t old = umask(0177);
    rc = uv_pipe_bind(&d->listener, c->socket);
    umask(old);
    if (rc) {
        log_error("cannot bind %s: %s", c->socket, uv_strerror(rc));
        return rc;
    }
    if (c->has_socket_group && chown(c->socket, (uid_t)-1, c->socket_gid) != 0) {
        log_error("cannot give %s to group %s: %s", c->socket, c->socket_group,
                  strerror(errno));
        return -errno;
    }
    if (chmod(c->socket, c->socket_mode) != 0) {
        log_error("cannot chmod %s: %s", c->socket, strerror(errno));
        return -errno;
    }
    rc = uv_listen((uv_stream_t *)&d->listener, 128, daemon_on_connection);
    if (rc) log_error("cannot listen on %s: %s", c->socket, uv_strerror(rc));
    return rc;
}

static void stop_listening(daemon_ctx *d)
{
    if (!d->listening) return;
    d->listening = 0;
    /* A worker closes what it inherits as it starts (worker.c), but one
     * being forked this instant may hold a copy for a moment: shutdown
     * makes connects fail now, whoever still has a descriptor. */
    uv_os_fd_t fd;
    if (uv_fileno((uv_handle_t *)&d->listener, &fd) == 0) shutdown(fd, SHUT_RDWR);
    uv_close((uv_handle_t *)&d->listener, NULL);
}

/* ---------------------------------------------------------------- stopping */

static void close_handle(uv_handle_t *h)
{
    if (!uv_is_closing(h)) uv_close(h, NULL);
}

static void on_stop_timer(uv_timer_t *t)
{
    daemon_ctx *d = t->data;
    log_warn("clients did not read their last replies in time; closing them");
    while (d->clients) daemon_client_close(d->clients);
}

/* Everything is done: close the remaining clients once their replies are
 * written (bounded by the stop timer), then the engine, then the loop.
 * Runs after every turn of the loop (on_loop_turn), so what ends a job, an
 * upload or a connection need not call up here. */
static void maybe_exit(daemon_ctx *d)
{
    if (!d->stopping || d->exiting || daemon_busy(d) || d->nuploading) return;
    for (daemon_client *c = d->clients, *next; c; c = next) {
        next = c->next;
        daemon_client_close_after_flush(c);
    }
    if (d->clients) {
        if (!uv_is_active((uv_handle_t *)&d->stop_timer))
            uv_timer_start(&d->stop_timer, on_stop_timer, DAEMON_STOP_GRACE_MS, 0);
        return;
    }
    d->exiting = 1;
    stop_listening(d);
    daemon_engine_stop(d); /* the workers exit, the segment is removed */
    uv_handle_t *hs[] = {(uv_handle_t *)&d->sig_term, (uv_handle_t *)&d->sig_int,
                         (uv_handle_t *)&d->sig_quit, (uv_handle_t *)&d->sig_hup,
                         (uv_handle_t *)&d->sig_usr1, (uv_handle_t *)&d->tick,
                         (uv_handle_t *)&d->stop_timer, (uv_handle_t *)&d->wake,
                         (uv_handle_t *)&d->turn};
    for (size_t i = 0; i < sizeof hs / sizeof hs[0]; i++) close_handle(hs[i]);
    log_info("stopped");
}

/* TERM/INT: uploading, queued and delivering jobs end with SHUTTING_DOWN
 * now, the running one is cancelled and ends with it when the engine
 * returns. */
static void stop_fast(daemon_ctx *d)
{
    if (d->stopping == DAEMON_STOP_FAST) return;
    d->stopping = DAEMON_STOP_FAST;
    log_info("stopping now: jobs end with SHUTTING_DOWN");
    stop_listening(d);
    pthread_mutex_lock(&d->mu);
    daemon_job *q = d->queue;
    d->queue = d->queue_tail = NULL;
    d->nqueued = 0;
    if (d->running && !d->running->cancel_code) {
        d->running->cancel_code = VOXD__ERROR_CODE__SHUTTING_DOWN;
        atomic_store_explicit(&d->running->cancel, 1, memory_order_relaxed);
    }
    pthread_mutex_unlock(&d->mu);
    while (q) {
        daemon_job *j = q;
        q = q->next;
        daemon_job_fail(d, j, VOXD__ERROR_CODE__SHUTTING_DOWN, "the daemon is stopping");
    }
    for (daemon_client *c = d->clients; c; c = c->next)
        daemon_client_fail_uploads(c, VOXD__ERROR_CODE__SHUTTING_DOWN, "the daemon is stopping");
    for (daemon_client *c = d->clients; c; c = c->next)
        while (c->deliver) {
            daemon_job *j = c->deliver;
            c->deliver = j->next;
            if (!c->deliver) c->deliver_tail = NULL;
            daemon_job_fail(d, j, VOXD__ERROR_CODE__SHUTTING_DOWN, "the daemon is stopping");
        }
    uv_timer_start(&d->stop_timer, on_stop_timer, DAEMON_STOP_GRACE_MS, 0);
}

/* QUIT: no new connections or jobs; the uploading, queued and running ones
 * finish (an upload that stalls ends after the client timeout). */
static void stop_graceful(daemon_ctx *d)
{
    if (d->stopping) return;
    d->stopping = DAEMON_STOP_GRACEFUL;
    log_info("stopping when the running and queued jobs are done");
    stop_listening(d);
}

/* ---------------------------------------------------------------- reload */

static void reload(daemon_ctx *d)
{
    voxd_config nc;
    err_info err = {0};
    if (daemon_load_config(&d->opt, &nc, &err)) {
        log_error("reload: %s; keeping the running configuration", err.msg);
        return;
    }
    if (strcmp(nc.socket, d->cfg.socket)) {
        log_warn("reload: a new socket path takes effect at the next start");
        memcpy(nc.socket, d->cfg.socket, sizeof nc.socket);
    }
    if (strcmp(nc.log_file, d->cfg.log_file) || nc.log_level != d->cfg.log_level) {
        int rc = log_open(nc.log_file, "voxd", nc.log_level);
        if (rc) log_error("reload: cannot open %s: %s", nc.log_file, strerror(-rc));
    }
    d->cfg = nc;
    pthread_mutex_lock(&d->mu);
    daemon_engine_opts(d, &nc);
    d->reload = 1;
    pthread_cond_signal(&d->cv);
    pthread_mutex_unlock(&d->mu);
    log_info("configuration reloaded; the workers are replaced between jobs");
}

/* ---------------------------------------------------------------- signals, timer */

static void on_signal(uv_signal_t *s, int signum)
{
    daemon_ctx *d = s->data;
    switch (signum) {
    case SIGTERM: case SIGINT: stop_fast(d); break;
    case SIGQUIT: stop_graceful(d); break;
    case SIGHUP: reload(d); break;
    case SIGUSR1: {
        int rc = log_reopen();
        if (rc) log_error("cannot reopen the log: %s", strerror(-rc));
        else log_info("log reopened");
        break;
    }
    }
}

static int watch_signals(daemon_ctx *d)
{
    struct { uv_signal_t *h; int sig; } sigs[] = {
        {&d->sig_term, SIGTERM}, {&d->sig_int, SIGINT}, {&d->sig_quit, SIGQUIT},
        {&d->sig_hup, SIGHUP}, {&d->sig_usr1, SIGUSR1}};
    for (size_t i = 0; i < sizeof sigs / sizeof sigs[0]; i++) {
        int rc = uv_signal_init(d->loop, sigs[i].h);
        if (rc) return rc;
        sigs[i].h->data = d;
        if ((rc = uv_signal_start(sigs[i].h, on_signal, sigs[i].sig))) return rc;
    }
    return 0;
}

/* The running job past its job_timeout is told to stop. */
static void check_job_timeout(daemon_ctx *d, double now)
{
    pthread_mutex_lock(&d->mu);
    daemon_job *j = d->running;
    int late = j && j->job_timeout && !j->cancel_code &&
               now - j->t_start > (double)j->job_timeout;
    if (late) {
        j->cancel_code = VOXD__ERROR_CODE__TIMEOUT;
        atomic_store_explicit(&j->cancel, 1, memory_order_relaxed);
    }
    pthread_mutex_unlock(&d->mu);
    if (late)
        log_info("job %llu: past job_timeout (%u s); stopping it",
                 (unsigned long long)j->id, j->job_timeout);
}

static void on_tick(uv_timer_t *t)
{
    daemon_ctx *d = t->data;
    double now = clock_now();
    check_job_timeout(d, now);
    /* a flood that stopped: its count is written now, not at the next one */
    for (int k = 0; k < DAEMON_LOG_KINDS; k++) log_limit_flush(&d->loglim[k], now);
    for (daemon_client *c = d->clients, *next; c; c = next) {
        next = c->next;
        daemon_client_tick(c, now);
    }
}

/* ---------------------------------------------------------------- run */

/* --daemon: tell the waiting parent we serve, then let go of the terminal. */
static void ready(daemon_ctx *d)
{
    if (d->opt.ready_fd < 0) return;
    ssize_t w = write(d->opt.ready_fd, "1", 1);
    (void)w;
    close(d->opt.ready_fd);
    d->opt.ready_fd = -1;
    int fd = open("/dev/null", O_RDWR | O_CLOEXEC);
    if (fd < 0) return;
    dup2(fd, 0);
    dup2(fd, 1);
    dup2(fd, 2); /* the log is in its file or syslog: nothing goes to the terminal */
    close(fd);
}

static void on_loop_turn(uv_check_t *h)
{
    maybe_exit(h->data);
}

static int start(daemon_ctx *d)
{
    int rc = uv_async_init(d->loop, &d->wake, daemon_on_wake);
    if (rc) return rc;
    d->wake.data = d;
    uv_check_init(d->loop, &d->turn);
    d->turn.data = d;
    uv_check_start(&d->turn, on_loop_turn);
    uv_timer_init(d->loop, &d->tick);
    uv_timer_init(d->loop, &d->stop_timer);
    d->tick.data = d->stop_timer.data = d;
    if ((rc = watch_signals(d))) return rc;
    /* The workers first: forked before the socket exists, they do not
     * hold it. */
    if ((rc = daemon_engine_start(d))) {
        log_error("cannot start the workers: %s", d->engine_err[0] ? d->engine_err : strerror(-rc));
        return rc;
    }
    if ((rc = listen_on(d))) return rc;
    uv_timer_start(&d->tick, on_tick, DAEMON_TICK_MS, DAEMON_TICK_MS);
    char stall[32] = "off";
    if (d->cfg.worker_stall_timeout)
        snprintf(stall, sizeof stall, "%u s", d->cfg.worker_stall_timeout);
    log_info("listening on %s: %d worker%s, shared memory %s, client timeout %u s, "
             "worker stall timeout %s, memory budget %llu MiB",
             d->cfg.socket, d->nworkers, d->nworkers == 1 ? "" : "s", d->shm_name, d->cfg.client_timeout, stall,
             (unsigned long long)(config_max_memory(&d->cfg) >> 20));
    return 0;
}

static void walk_close(uv_handle_t *h, void *arg)
{
    (void)arg;
    close_handle(h);
}

static void init_log_limits(daemon_ctx *d)
{
    static const char *const what[DAEMON_LOG_KINDS] = {
        [DAEMON_LOG_ACCEPT] = "failed accepts",
        [DAEMON_LOG_NOT_ALLOWED] = "refused connections: not in allow_uids",
        [DAEMON_LOG_PER_UID] = "refused connections: max_clients_per_uid",
        [DAEMON_LOG_FULL] = "refused connections: max_clients",
        [DAEMON_LOG_BAD_FRAME] = "bad frames",
        [DAEMON_LOG_BAD_REQUEST] = "refused requests",
        [DAEMON_LOG_STALLED] = "clients timed out",
        [DAEMON_LOG_CUT] = "connections ended inside a frame",
    };
    for (int k = 0; k < DAEMON_LOG_KINDS; k++) d->loglim[k] = (log_limit)LOG_LIMIT_INIT(what[k]);
}

int daemon_run(const voxd_config *cfg, const daemon_options *opt, const char *shm_name)
{
    daemon_ctx *d = calloc(1, sizeof *d);
    uv_loop_t loop;
    if (!d || uv_loop_init(&loop)) {
        free(d);
        log_error("out of memory");
        return CLI_EXIT_FAILED;
    }
    d->loop = &loop;
    d->cfg = *cfg;
    d->opt = *opt;
    snprintf(d->shm_name, sizeof d->shm_name, "%s", shm_name);
    d->t_start = clock_now();
    init_log_limits(d);
    pthread_mutex_init(&d->mu, NULL);
    pthread_cond_init(&d->cv, NULL);
    pthread_cond_init(&d->started_cv, NULL);
    daemon_engine_opts(d, cfg);
    int rc = start(d);
    if (rc == 0) {
        ready(d);
        uv_run(&loop, UV_RUN_DEFAULT);
    } else {
        d->exit_code = CLI_EXIT_FAILED;
    }
    daemon_engine_stop(d);
    uv_walk(&loop, walk_close, NULL);
    uv_run(&loop, UV_RUN_DEFAULT);
    uv_loop_close(&loop);
    pthread_cond_destroy(&d->started_cv);
    pthread_cond_destroy(&d->cv);
    pthread_mutex_destroy(&d->mu);
    rc = d->exit_code;
    free(d);
    return rc;
}
