//! Stage search: the smallest codec meeting an error budget.
