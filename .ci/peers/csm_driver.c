/*
 * csm_driver: scan-to-scan odometry with CSM's PL-ICP (sm_icp) for csm_peer.py.
 *
 * Dev tooling of laser_odom (not part of the installed package). Reads the scans
 * that csm_peer.py writes, matches every scan against the one before it with
 * sm_icp(), chains the steps into poses and writes one line per scan.
 *
 * Input (text, one record per line, '#' lines ignored):
 *   csm_peer_scans 1 <scans>
 *   <stamp_ns> <cv_ratio> <n> <angle_min> <angle_increment> <range_min> <range_max>
 *       <r_1> ... <r_n>                                   (one line per scan)
 * A reading is valid when range_min < r < range_max (as laser_scan_matcher does);
 * "inf" and "nan" are accepted and invalid.
 *
 * First guess (constant velocity): cv_ratio times the previous step's (x, y, theta).
 * csm_peer.py makes cv_ratio 1 (the previous step repeated), or the time gap over the
 * previous step's gap, and 0 when there is nothing to scale (the first match, or
 * after a gap in the stamps).
 * When sm_icp reports valid == 0 the step is the first guess (the prediction), and
 * the next guess is zero motion (the pipeline's motion model also forgets its velocity
 * after a failed match).
 *
 * Output (stdout): a header line, then per scan
 *   <stamp_ns> <x> <y> <theta> <valid> <iterations> <nvalid> <sm_icp_seconds>
 * valid is -1 for the first scan (nothing matched), else sm_icp's valid flag.
 *
 * Parameters: preset=ros (the default) takes laser_scan_matcher's defaults (scan_tools,
 * ROS), preset=csm CSM's own (sm_options.c); any can be overridden with name=value
 * arguments, e.g. "max_iterations=20". --params prints those in use and exits.
 */

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <csm/csm_all.h>

#define MAX_RAYS 10000

enum kind { INT_PARAM, DOUBLE_PARAM };

struct param_entry {
	const char *name;
	enum kind kind;
	size_t offset;
	double ros;   /* laser_scan_matcher's default (preset=ros) */
	double csm;   /* CSM's own default, sm_options.c (preset=csm) */
	double value; /* in use */
};

#define P_INT(name, ros, csm) {#name, INT_PARAM, offsetof(struct sm_params, name), ros, csm, ros}
#define P_DBL(name, ros, csm) {#name, DOUBLE_PARAM, offsetof(struct sm_params, name), ros, csm, ros}

/*
 * ros: the defaults laser_scan_matcher (CCNYRoboticsLab/scan_tools,
 *      src/laser_scan_matcher.cpp) gives CSM - how ROS users run PL-ICP (the default).
 * csm: CSM's own defaults (sm/csm/sm_options.c), those of its sm1/sm2 programs.
 */
static struct param_entry params_table[] = {
	P_DBL(max_angular_correction_deg, 45.0, 90.0),
	P_DBL(max_linear_correction, 0.50, 2.0),
	P_INT(max_iterations, 10, 1000),
	P_DBL(epsilon_xy, 0.000001, 0.0001),
	P_DBL(epsilon_theta, 0.000001, 0.0001),
	P_DBL(max_correspondence_dist, 0.3, 2.0),
	P_DBL(sigma, 0.010, 0.01),
	P_INT(use_corr_tricks, 1, 1),
	P_INT(restart, 0, 1),
	P_DBL(restart_threshold_mean_error, 0.01, 0.01),
	P_DBL(restart_dt, 1.0, 0.01),
	P_DBL(restart_dtheta, 0.1, 0.026179938779914941),
	P_DBL(clustering_threshold, 0.25, 0.05),
	P_INT(orientation_neighbourhood, 20, 3),
	P_INT(use_point_to_line_distance, 1, 1),
	P_INT(do_alpha_test, 0, 0),
	P_DBL(do_alpha_test_thresholdDeg, 20.0, 20.0),
	P_DBL(outliers_maxPerc, 0.90, 0.95),
	P_DBL(outliers_adaptive_order, 0.7, 0.7),
	P_DBL(outliers_adaptive_mult, 2.0, 2.0),
	P_INT(do_visibility_test, 0, 0),
	P_INT(outliers_remove_doubles, 1, 1),
	P_INT(do_compute_covariance, 0, 0),
	P_INT(debug_verify_tricks, 0, 0),
	P_INT(use_ml_weights, 0, 0),
	P_INT(use_sigma_weights, 0, 0),
};

#define N_PARAMS (sizeof(params_table) / sizeof(params_table[0]))

static void set_param(struct sm_params *p, const struct param_entry *e, double value)
{
	char *field = (char *)p + e->offset;
	if (e->kind == INT_PARAM)
		*(int *)field = (int)value;
	else
		*(double *)field = value;
}

static int override_param(struct sm_params *p, const char *arg)
{
	const char *eq = strchr(arg, '=');
	if (!eq)
		return 0;
	size_t len = (size_t)(eq - arg);
	for (size_t i = 0; i < N_PARAMS; i++) {
		if (strlen(params_table[i].name) == len &&
		    strncmp(params_table[i].name, arg, len) == 0) {
			char *end;
			double value = strtod(eq + 1, &end);
			if (end == eq + 1 || *end != '\0')
				return 0;
			params_table[i].value = value;
			set_param(p, &params_table[i], value);
			return 1;
		}
	}
	return 0;
}

static double now_seconds(void)
{
	struct timespec t;
	clock_gettime(CLOCK_MONOTONIC, &t);
	return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* Read one scan line into a new LDP; returns NULL at end of input. */
static LDP read_scan(FILE *in, long long *stamp_ns, double *cv_ratio,
		     double *range_min, double *range_max)
{
	int n;
	double angle_min, increment;
	if (fscanf(in, "%lld %lf %d %lf %lf %lf %lf", stamp_ns, cv_ratio, &n, &angle_min,
		   &increment, range_min, range_max) != 7)
		return NULL;
	if (n < 2 || n > MAX_RAYS) {
		fprintf(stderr, "csm_driver: scan at %lld has %d rays\n", *stamp_ns, n);
		exit(2);
	}
	LDP ld = ld_alloc_new(n);
	char token[64];
	for (int i = 0; i < n; i++) {
		if (fscanf(in, "%63s", token) != 1) {
			fprintf(stderr, "csm_driver: scan at %lld is short\n", *stamp_ns);
			exit(2);
		}
		double r = strtod(token, NULL);
		if (isfinite(r) && r > *range_min && r < *range_max) {
			ld->valid[i] = 1;
			ld->readings[i] = r;
		} else {
			ld->valid[i] = 0;
			ld->readings[i] = -1;
		}
		ld->theta[i] = angle_min + i * increment;
		ld->cluster[i] = -1;
	}
	ld->min_theta = ld->theta[0];
	ld->max_theta = ld->theta[n - 1];
	for (int k = 0; k < 3; k++) {
		ld->odometry[k] = 0.0;
		ld->estimate[k] = 0.0;
		ld->true_pose[k] = 0.0;
	}
	return ld;
}

/* pose = pose (+) step, both (x, y, theta). */
static void compose(double pose[3], const double step[3])
{
	double c = cos(pose[2]), s = sin(pose[2]);
	pose[0] += c * step[0] - s * step[1];
	pose[1] += s * step[0] + c * step[1];
	pose[2] = atan2(sin(pose[2] + step[2]), cos(pose[2] + step[2]));
}

int main(int argc, char **argv)
{
	struct sm_params params;
	struct sm_result result;
	memset(&params, 0, sizeof(params));
	memset(&result, 0, sizeof(result));
	const char *input_path = NULL;
	const char *preset = "ros";
	int list_only = 0;
	for (int a = 1; a < argc; a++)
		if (strncmp(argv[a], "preset=", 7) == 0)
			preset = argv[a] + 7;
	if (strcmp(preset, "ros") != 0 && strcmp(preset, "csm") != 0) {
		fprintf(stderr, "csm_driver: preset must be ros or csm, not %s\n", preset);
		return 2;
	}
	for (size_t i = 0; i < N_PARAMS; i++) {
		params_table[i].value = preset[0] == 'c' ? params_table[i].csm : params_table[i].ros;
		set_param(&params, &params_table[i], params_table[i].value);
	}
	for (int a = 1; a < argc; a++) {
		if (strncmp(argv[a], "preset=", 7) == 0)
			continue;
		if (strcmp(argv[a], "--params") == 0) {
			list_only = 1;
			continue;
		}
		if (strchr(argv[a], '=')) {
			if (!override_param(&params, argv[a])) {
				fprintf(stderr, "csm_driver: unknown or bad parameter %s\n", argv[a]);
				return 2;
			}
		} else {
			input_path = argv[a];
		}
	}
	if (list_only) {
		for (size_t i = 0; i < N_PARAMS; i++)
			printf("%s %.17g\n", params_table[i].name, params_table[i].value);
		return 0;
	}
	if (!input_path) {
		fprintf(stderr, "usage: csm_driver [preset=ros|csm] [name=value ...] "
			"(SCANS_FILE | --params)\n");
		return 2;
	}
	FILE *in = strcmp(input_path, "-") == 0 ? stdin : fopen(input_path, "r");
	if (!in) {
		perror(input_path);
		return 2;
	}
	char magic[32];
	int version, scans;
	if (fscanf(in, "%31s %d %d", magic, &version, &scans) != 3 ||
	    strcmp(magic, "csm_peer_scans") != 0 || version != 1) {
		fprintf(stderr, "csm_driver: %s is not a csm_peer_scans v1 file\n", input_path);
		return 2;
	}
	sm_set_program_name("csm_driver");

	printf("# stamp_ns x y theta valid iterations nvalid sm_icp_seconds; preset=%s", preset);
	for (size_t i = 0; i < N_PARAMS; i++)
		printf(" %s=%g", params_table[i].name, params_table[i].value);
	printf("\n");

	double pose[3] = {0, 0, 0}, last_step[3] = {0, 0, 0};
	LDP ref = NULL;
	long long stamp_ns;
	double cv_ratio, range_min, range_max;
	LDP sens;
	int count = 0;
	while ((sens = read_scan(in, &stamp_ns, &cv_ratio, &range_min, &range_max))) {
		count++;
		if (!ref) {
			printf("%lld %.9f %.9f %.9f -1 0 0 0\n", stamp_ns, pose[0], pose[1], pose[2]);
			ref = sens;
			continue;
		}
		double guess[3];
		for (int k = 0; k < 3; k++)
			guess[k] = cv_ratio * last_step[k];
		params.laser_ref = ref;
		params.laser_sens = sens;
		params.min_reading = range_min;
		params.max_reading = range_max;
		for (int k = 0; k < 3; k++) {
			params.first_guess[k] = guess[k];
			params.laser[k] = 0.0;
		}
		double started = now_seconds();
		sm_icp(&params, &result);
		double elapsed = now_seconds() - started;
		double step[3];
		for (int k = 0; k < 3; k++)
			step[k] = result.valid ? result.x[k] : guess[k];
		compose(pose, step);
		/* As the pipeline's motion model: no velocity after a failed match. */
		for (int k = 0; k < 3; k++)
			last_step[k] = result.valid ? step[k] : 0.0;
		printf("%lld %.9f %.9f %.9f %d %d %d %.9f\n", stamp_ns, pose[0], pose[1], pose[2],
		       result.valid, result.valid ? result.iterations : 0,
		       result.valid ? result.nvalid : 0, elapsed);
		ld_free(ref);
		ref = sens;
	}
	if (ref)
		ld_free(ref);
	if (count != scans) {
		fprintf(stderr, "csm_driver: read %d scans, header says %d\n", count, scans);
		return 2;
	}
	return 0;
}
