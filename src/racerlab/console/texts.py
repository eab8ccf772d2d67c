"""Words the console shows: one-line explanations of the hyperparameters."""

HYPERPARAMETER_HELP = {
    "batch_size": "Steps in each gradient-descent mini-batch; larger is steadier, slower to react.",
    "beta_entropy": "Weight of the entropy bonus: higher keeps the policy exploring longer (PPO).",
    "discount_factor": "How much future reward counts: 0.99 looks ~100 steps (7 s) ahead, 0.9 about 10.",
    "e_greedy_value": "Chance of a random action with e-greedy exploration (unused with categorical).",
    "epsilon_steps": "Steps over which e-greedy exploration decays (unused with categorical).",
    "exploration_type": "categorical samples actions from the policy (AWS default); e-greedy adds random ones.",
    "loss_type": "huber is robust to big reward jumps; mean squared error learns faster on small rewards.",
    "lr": "Learning rate of the optimiser: too high diverges, too low learns slowly (AWS default 0.0003).",
    "num_episodes_between_training": "Episodes collected per iteration before each policy update.",
    "num_epochs": "Passes over an iteration's data per update: more squeezes more from each episode.",
    "stack_size": "Frames stacked per observation (AWS keeps it at 1; accepted and ignored).",
    "term_cond_max_episodes": "Stop after this many episodes when no other stop condition is given.",
    "term_cond_avg_score": "Average reward at which AWS would stop (parsed, unused by racerlab).",
    "sac_alpha": "SAC's entropy temperature: higher explores more (SAC only).",
}
