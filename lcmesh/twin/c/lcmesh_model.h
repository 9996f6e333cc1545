/* lc-mesh twin: plant model state and entry points.
 * model_config.h is generated per system description (sizes, value-reference offsets). */
#ifndef LCMESH_MODEL_H
#define LCMESH_MODEL_H

#include "model_config.h"

typedef struct {
    double integ;     /* integral term, in error units */
    double deriv;     /* filtered derivative term, in error units */
    double meas_prev; /* measurement at the previous sub-step */
} PidState;

typedef struct {
    double r[N_REALS]; /* every FMI real, indexed by value reference */
    double time;

    /* thermal states (K) */
    double t_blade[NBG];
    double t_supply[NCAB];   /* CDU secondary outlet volume (coolant supply) */
    double t_return[NCAB];   /* cabinet coolant volume (return side) */
    double t_htw_supply, t_htw_return;
    double t_basin[NTOW];

    double valve_split[NCAB * NBR]; /* branch fractions as applied this step */

    /* actuators and inner controllers */
    double pump_speed[NCAB], valve_pos[NCAB];
    PidState dp_pid[NCAB], temp_pid[NCAB];
    double stuck_pos[NCAB];
    int stuck[NCAB];
    double fan_speed[NTOW], fan_integ[NTOW], leaving_temp[NTOW];
    int cells_on[NTOW];
    double stage_up_timer[NTOW], stage_down_timer[NTOW];

    /* energy accounting (J, since initialization) */
    double stored_energy_init;
    double energy_in, energy_rejected, energy_recovered;
} Model;

void model_init(Model *m);
/* Advance by h seconds; returns 0 on success, nonzero if the state became non-finite. */
int model_do_step(Model *m, double h);
/* Fill the outputs from the state right after initialization. */
void model_outputs_at_init(Model *m);

#endif
