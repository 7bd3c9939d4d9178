"""Networks, the TD3 update, and a trained policy: how it flies a design, its file and its export."""
