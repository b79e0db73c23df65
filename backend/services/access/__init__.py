"""Who acts: accounts, tokens and logins (auth), and the audit trail of what each actor did."""
