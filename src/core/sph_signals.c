/* Signals from batch schedulers (SIGTERM before a kill, SIGUSR1 as a warning): the handler
 * only records the signal; the run loop polls it after each step, writes a checkpoint and
 * stops cleanly (sph_signals.f90). */
#include <signal.h>
#include <string.h>

static volatile sig_atomic_t sph_received = 0;

static void sph_record(int signum) { sph_received = signum; }

/* Install the handler for SIGTERM and SIGUSR1; 0 on success. */
int sph_signals_install(void)
{
    struct sigaction action;
    memset(&action, 0, sizeof action);
    action.sa_handler = sph_record;
    sigemptyset(&action.sa_mask);
    action.sa_flags = SA_RESTART;
    if (sigaction(SIGTERM, &action, NULL) != 0) return 1;
    if (sigaction(SIGUSR1, &action, NULL) != 0) return 1;
    return 0;
}

/* The last signal received (0: none). */
int sph_signal_received(void) { return (int)sph_received; }
